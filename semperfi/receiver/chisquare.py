"""Chi-square quantiles for the detection thresholds, from scipy.special (importing scipy.stats costs a second,
which every run would pay)."""

from scipy import special


def chi2_isf(p, dof):
    """The level a chi-square variable with dof degrees of freedom exceeds with probability p."""
    return 2.0 * special.gammainccinv(dof / 2.0, p)


def chi2_median(dof):
    return chi2_isf(0.5, dof)


def ncx2_noncentrality(x, dof, p):
    """The non-centrality at which a non-central chi-square with dof degrees of freedom is at most x with
    probability p."""
    return special.chndtrinc(x, dof, p)

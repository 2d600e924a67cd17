"""The world's fast Gaussian noise against numpy's normal draw (the slow reference)."""

import numpy as np
from scipy import stats

from semperfi.sim.noise import gaussian


def test_fast_noise_is_white_unit_gaussian_like_numpys_and_repeats_with_its_seed():
    n = 2_000_000
    drawn = gaussian(np.random.default_rng(5), n)
    assert drawn.dtype == np.float32 and drawn.size == n
    assert np.array_equal(drawn, gaussian(np.random.default_rng(5), n)), "the same seed, the same noise"
    x = drawn.astype(np.float64)
    # mean and variance within 5 standard errors of N(0, 1)'s (var of a sample variance: 2 / n)
    assert abs(np.mean(x)) < 5 / np.sqrt(n) and abs(np.var(x) - 1) < 5 * np.sqrt(2 / n), (np.mean(x), np.var(x))
    # white: neighbours and words' lanes (four draws share a 64-bit word) uncorrelated
    for lag in (1, 2, 3, 4, 5):
        assert abs(np.mean(x[:-lag] * x[lag:])) < 5 / np.sqrt(n), lag
    # its distribution is numpy's to the table's resolution (2^16 bins): a two-sample KS test cannot tell them apart
    reference = np.random.default_rng(6).standard_normal(n)
    assert stats.ks_2samp(x, reference).pvalue > 1e-3

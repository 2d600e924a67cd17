"""How much one buffer says of where a spoofer's twin is: the joint fit's separation and its variance."""

import numpy as np
import pytest

from semperfi.defense.chip_shape import code_correlation
from semperfi.defense.twopath_track import bank_lags, fit_two_paths

PRN, TWIN_CHIPS, PERIODS = 8, 0.4, 100
NOISE = 0.05 ** 2                 # one period's correlation variance: a unit spoofer at ~43 dB-Hz in 1 ms


def buffers(relative_phase_rad: float, draws: int, seed: int = 5):
    """Correlations of a unit spoofer and its twin (half as strong, TWIN_CHIPS off, their carriers locked at
    relative_phase_rad) over PERIODS code periods with white noise, `draws` times."""
    rng = np.random.default_rng(seed)
    lags = bank_lags(TWIN_CHIPS)
    spoofer = np.exp(1j * rng.uniform(0, 2 * np.pi, PERIODS))
    twin = 0.5 * spoofer * np.exp(1j * relative_phase_rad)
    clean = np.outer(spoofer, code_correlation(PRN, lags)) + np.outer(twin, code_correlation(PRN, lags - TWIN_CHIPS))
    # the noise correlated between the lags as the code is with itself (what the bank of a white noise holds)
    root = np.linalg.cholesky(code_correlation(PRN, lags[:, None] - lags[None, :]) + 1e-9 * np.eye(lags.size))
    for _ in range(draws):
        noise = (rng.standard_normal((PERIODS, lags.size)) + 1j * rng.standard_normal((PERIODS, lags.size)))
        yield lags, clean + np.sqrt(NOISE / 2) * noise @ root.T


@pytest.mark.parametrize("relative_phase_rad", [np.pi / 2, 0.0, 2.5])
def test_the_separations_predicted_variance_is_what_its_fits_scatter_by(relative_phase_rad):
    """Over 200 seeded buffers the fitted separation scatters about the truth by what its predicted variance (the
    likelihood's curvature) says, within a factor of two, whatever the twin's carrier against its spoofer's: what
    weighs each buffer in the offset the canceller carries."""
    fits = [fit_two_paths(PRN, y, lags, TWIN_CHIPS, NOISE) for lags, y in buffers(relative_phase_rad, 200)]
    separations = np.array([f.separation_chips for f in fits])
    scatter = float(np.var(separations))
    predicted = float(np.median([f.separation_var_chips2 for f in fits]))
    print(f"scatter {np.sqrt(scatter):.4f} chip, predicted {np.sqrt(predicted):.4f} chip")
    assert abs(np.mean(separations) - TWIN_CHIPS) < 3 * np.sqrt(scatter / len(fits)) + 0.002
    assert 0.5 < predicted / scatter < 2.0

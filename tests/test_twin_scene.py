"""scripts/twin-bias-map's reading of a twin (semperfi.eval.twin_scene) against a loop's balance worked by hand."""

import numpy as np
import pytest
from scipy.optimize import brentq

from semperfi.defense.chip_shape import code_correlation
from semperfi.eval.twin_scene import ca_signal, early_late_balance_chips


@pytest.mark.parametrize("half_spacing_chips", [0.25, 0.5])
def test_an_echo_moves_the_early_late_reading_where_the_codes_correlations_balance(half_spacing_chips):
    """An echo a tenth as strong, in phase, 0.8 chip late (noise-free, 2.6 MSa/s: the samples slide over the chips,
    so the correlation is the code's own, linear between whole chips). The loop balances where
    |R(e - h) + 0.1 R(e - h - 0.8)| = |R(e + h) + 0.1 R(e + h - 0.8)|, R the code's autocorrelation (PRN 7's is
    +63/1023 at one chip, which the early correlator reaches at h = 0.5): 0.0238 and 0.0378 chip (7.0 and 11.1 m)."""
    fs, prn, doppler, h = 2.6e6, 7, -1300.0, half_spacing_chips
    t = np.arange(int(0.5 * fs)) / fs
    direct = ca_signal(prn, t, 400.0, doppler, 1.0, 0.3)
    echo = ca_signal(prn, t, 400.8, doppler, 0.1, 0.3)
    alone = early_late_balance_chips(direct, fs, prn, 400.0, doppler, h, 0.0)
    moved = early_late_balance_chips(direct + echo, fs, prn, 400.0, doppler, h, 0.0)

    def balance(e):
        def at(lag):
            return abs(code_correlation(prn, lag) + 0.1 * code_correlation(prn, lag - 0.8))
        return at(e - h) - at(e + h)

    assert abs(alone) < 0.001
    assert moved - alone == pytest.approx(brentq(balance, -0.1, 0.2), abs=0.001)

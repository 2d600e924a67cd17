"""Claims about RINEX 3 observation output: georinex reads back exactly what the receiver measured."""

import math

import numpy as np
import pytest

from semperfi.receiver.rinex_obs import ObsEpoch, write_rinex_obs

georinex = pytest.importorskip("georinex", reason="georinex is not installed")


def test_georinex_reads_back_c1c_l1c_d1c_s1c(tmp_path):
    epochs = [ObsEpoch(2190, 518400.0 + k, {5: (21_000_123.456 + 700.0 * k, math.nan if k == 0 else 1234.5 * k,
                                                -1523.25, 44.5),
                                            17: (23_456_789.012 - 300.0 * k, 98765.25, 2210.5, 38.0)})
              for k in range(3)]
    path = write_rinex_obs(tmp_path / "run.obs", epochs, approx_xyz_m=(4e6, 1e5, 4.9e6))
    obs = georinex.load(path)
    assert obs.time.size == 3
    # Week 2190, TOW 518400 s is 2022-01-01 00:00:00 GPS time (RINEX keeps GPS time, no leap seconds).
    assert str(obs.time.values[0])[:19] == "2022-01-01T00:00:00", obs.time.values[0]
    c1c = obs["C1C"].sel(sv="G05").values
    assert np.allclose(c1c, [21_000_123.456 + 700.0 * k for k in range(3)], atol=1e-3), c1c
    assert np.isnan(obs["L1C"].sel(sv="G05").values[0]) and obs["L1C"].sel(sv="G05").values[2] == pytest.approx(2469.0)
    assert np.allclose(obs["D1C"].sel(sv="G17").values, 2210.5) and np.allclose(obs["S1C"].sel(sv="G17").values, 38.0)


def test_nothing_to_write_is_one_error(tmp_path):
    with pytest.raises(ValueError, match="no observation epochs"):
        write_rinex_obs(tmp_path / "empty.obs", [])

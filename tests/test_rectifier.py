"""The pseudorange rectifier's arithmetic: the legitimate signal's transmit time is the spoofer's plus the two code
phases' offset; the whole milliseconds from the receiver's clock when it has one, else within half a millisecond."""

from types import SimpleNamespace

import numpy as np
import pytest

from semperfi.defense.rectifier import Rectifier
from semperfi.receiver.tracking import Channel, initial_state

FS_HZ = 2.6e6
T0_S = 345_600.0          # the transmit time of the adversary's code epoch 0
BASE = 10_000             # the absolute sample at which that epoch arrives
PERIODS = 3000
PERIOD = FS_HZ * 1e-3 * (1.0 - 1200.0 / 1575.42e6)   # samples per code period at a 1200 Hz Doppler


def _channel(delay_s: float) -> Channel:
    """A channel that has tracked a signal whose code epoch k (sent at T0 + k ms) arrived delay_s after the
    adversary's epoch k, at a Doppler that stretches the code period."""
    ch = Channel(5, FS_HZ, 0.0, initial_state(0.0, 0, 0.0, FS_HZ, 0))
    ch.epoch_sample[:PERIODS] = BASE + delay_s * FS_HZ + PERIOD * np.arange(PERIODS)
    ch.ms = PERIODS
    ch.bits.edge_ms = 0
    return ch


class _Track(SimpleNamespace):
    __hash__ = object.__hash__      # the rectifier keys its decoders by track, as the canceller's are


def _lag_s(delay_s: float) -> float:
    """The transmit-time lag of a signal arriving delay_s later: a code period holds 1 ms of transmit time."""
    return delay_s * FS_HZ / PERIOD * 1e-3


def _rectifier(adversary: Channel, eph) -> Rectifier:
    r = Rectifier("always")
    track = _Track(prn=5, stage=0, channel=adversary)
    r._decoders[track] = SimpleNamespace(time_anchor=(0, T0_S), ephemeris=eph)   # bit 0 starts at epoch 0
    return r


@pytest.mark.parametrize("delay_s", [3.3e-6, -0.31e-3, 0.42e-3])
def test_the_legitimate_transmit_time_is_the_spoofers_plus_the_code_offset(delay_s):
    """Without a clock to say the whole milliseconds: right while the two are within half a code period."""
    adversary, legit = _channel(0.0), _channel(delay_s)
    sample = BASE + 1234.567 * FS_HZ * 1e-3
    r = _rectifier(adversary, "eph")
    got = r.rectify(5, legit, sample, lambda prn, t: None, lambda eph, s: None)
    t_at = adversary.transmit_time_at(sample, 0, T0_S)
    assert got is not None and got.ephemeris == "eph"
    assert abs(got.t_sv_s - (t_at - _lag_s(delay_s))) < 1e-9, (got.t_sv_s - t_at, -delay_s)
    assert abs(got.offset_s + _lag_s(delay_s)) < 1e-9


def test_whole_milliseconds_come_from_the_receiver_clock_and_a_spoofer_far_from_it_is_refused():
    delay_s = 2.37e-3                       # a spoofer 2.37 ms ahead of the legitimate signal
    adversary, legit = _channel(0.0), _channel(delay_s)
    sample = BASE + 800.25 * FS_HZ * 1e-3
    truth = adversary.transmit_time_at(sample, 0, T0_S) - _lag_s(delay_s)
    r = _rectifier(adversary, "eph")
    blind = r.rectify(5, legit, sample, lambda prn, t: "own", lambda eph, s: None)
    assert blind.ephemeris == "own" and abs(blind.t_sv_s - (truth + 2e-3)) < 1e-9   # the half-period assumption fails
    clocked = r.rectify(5, legit, sample, lambda prn, t: "own", lambda eph, s: truth + 40e-6)   # a 12 km prior error
    assert abs(clocked.t_sv_s - truth) < 1e-9
    # the receiver's clock says the spoofer's time is 15 ms off: not taken
    assert r.rectify(5, legit, sample, lambda prn, t: "own", lambda eph, s: truth - 15e-3) is None
    assert r.refused[5] == "-17 ms from the receiver clock's prediction"   # 15 ms, and the 2 ms blind guess


def test_only_prns_whose_spoofer_is_followed_are_rectified():
    r = _rectifier(_channel(0.0), "eph")
    assert r.wants(5, has_own_time=True) and not r.wants(6, has_own_time=False)
    auto = Rectifier("auto")
    auto._decoders = r._decoders
    assert auto.wants(5, has_own_time=False) and not auto.wants(5, has_own_time=True)
    assert not Rectifier("off").wants(5, has_own_time=False)
    with pytest.raises(ValueError, match="defense.rectify"):
        Rectifier("sometimes")

"""Under a known attack, a PRN that shows one peak is looked at longer: a twin too weak to show beside its spoofer
in the regular examinations (2 ms x 20 under the attacker's interference) is found, and its spoofer cancelled,
instead of passing through `clean` to the receiver behind it (GPS-SDR-SIM, path loss: 22 s before)."""

import numpy as np
import pytest

from semperfi.defense.config import load_config
from semperfi.defense import guard as guard_module
from semperfi.defense.guard import SpoofGuard
from semperfi.gps.codes import ca_code, chips_apart

FS = 2.6e6
SECONDS = 3.0
CHUNK = int(0.1 * FS)
DOPPLER_HZ = {5: 1200.0, 9: -2300.0, 14: 400.0}
# PRN 5: a plain alarm (spoofer 50 dB-Hz, twin 44 dB-Hz 3 chips off) makes the attack known; PRN 9: a spoofer at
# 42 dB-Hz and its twin at 35 dB-Hz 2.9 chips off; PRN 14: a satellite alone (no spoofer), 42 dB-Hz
SIGNALS = [(5, 100.0, 50.0), (5, 103.0, 44.0), (9, 400.0, 42.0), (9, 397.1, 35.0), (14, 700.0, 42.0)]


class Events:
    def __init__(self):
        self.rows = []

    def emit(self, kind, t_s, **fields):
        self.rows.append({"event": kind, "t_s": t_s, **fields})


def _samples(seed: int = 7) -> np.ndarray:
    """The signals (no data bits) in unit complex noise: amplitude sqrt(C/N0 x 2 / fs)."""
    rng = np.random.default_rng(seed)
    n = int(SECONDS * FS)
    t = np.arange(n) / FS
    x = (rng.standard_normal(n) + 1j * rng.standard_normal(n)).astype(np.complex64)
    for prn, chips, cn0 in SIGNALS:
        code = ca_code(prn).astype(np.float32)
        idx = np.floor(chips + t * 1.023e6 * (1 + DOPPLER_HZ[prn] / 1575.42e6)).astype(np.int64) % 1023
        amp = np.sqrt(10 ** (cn0 / 10) * 2 / FS)
        x += (amp * code[idx] * np.exp(2j * np.pi * (DOPPLER_HZ[prn] * t + 0.1 * prn))).astype(np.complex64)
    return x


@pytest.fixture(scope="module")
def samples():
    return _samples()


def _guard_over(samples) -> Events:
    events = Events()
    guard = SpoofGuard(load_config(None, []), FS, 0.0, events)
    for i in range(0, samples.size, CHUNK):
        guard.push(samples[i:i + CHUNK])
    guard.flush()
    return events


def _alarms(events):
    return {r["prn"]: r for r in events.rows if r["event"] == "spoofing_alarm"}


def test_a_twin_too_weak_for_the_examinations_is_found_by_the_longer_look(samples):
    alarms = _alarms(_guard_over(samples))
    assert 5 in alarms and alarms[5]["found_by"] != "deep"
    assert 9 in alarms and alarms[9]["found_by"] == "deep", alarms.get(9)
    assert alarms[9]["t_s"] < 2.0
    # the spoofer is the stronger peak (its code phase at the look's first sample), the twin 2.9 chips from it
    spoofer_chips = (400.0 + alarms[9]["t_s"] * 1.023e6 * (1 + DOPPLER_HZ[9] / 1575.42e6)) % 1023
    assert chips_apart(alarms[9]["main"]["code_phase_chips"], spoofer_chips) < 0.3
    assert alarms[9]["separation_chips"] == pytest.approx(2.9, abs=0.3)
    assert 14 not in alarms                   # a satellite alone is never alarmed by the longer look


def test_without_the_longer_look_that_twin_is_not_found(samples, monkeypatch):
    monkeypatch.setattr(guard_module.SpoofGuard, "_look_deeper", lambda self, cafs: None)
    alarms = _alarms(_guard_over(samples))
    assert 5 in alarms and 9 not in alarms

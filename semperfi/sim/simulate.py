"""The simulator: renders the legitimate constellation, the attacker and noise, chunk by chunk, with its truth.

Time model. Sample k is taken when the receiver's clock reads T0 + k/fs; the clock runs ahead of GPS time by
b(tau) = b0 + drift * tau, and its oscillator drives the sample clock and the local oscillator alike. A signal whose
pseudorange is P (metres, receiver clock included) therefore arrives with code time t_sv = t_rx - P/c and carrier
phase -P_carrier / lambda (+ IF), which keeps code, carrier and Doppler consistent by construction.
"""

import math
from dataclasses import dataclass, replace
from typing import Callable, Iterator

import numpy as np

from ..gps import (CA_CHIP_RATE_HZ, CHIPS_PER_BIT, L1_WAVELENGTH_M, NAV_BIT_RATE_HZ, SPEED_OF_LIGHT_M_S, ca_code,
                   geodetic_to_ecef, quantize_ephemeris, stack_ephemerides)
from .attacker import AttackPlan
from .constellation import Constellation, build_constellation
from .motion import LiveMotion, StaticMotion, TrajectoryMotion
from .navstream import NavStream
from .propagation import arrival
from .render import render
from .scenario import FORMAT_NOISE_RMS, REAL_FORMATS

CHUNK_S = 0.02   # pseudoranges are interpolated linearly within a chunk: < 1 mm at 10 m/s^2


@dataclass
class _Signal:
    source: str               # legit | spoof | multipath
    prn: int
    nav: NavStream
    phase_offset_cycles: float
    extra_delay_m: float = 0.0


@dataclass(frozen=True)
class SignalTruth:
    """One signal as it arrives at the antenna at t_rx_s (receiver clock, seconds since the first sample)."""
    t_rx_s: float
    prn: int
    source: str
    code_phase_chips: float   # chip of the C/A code arriving at that sample, in [0, 1023)
    doppler_hz: float
    carrier_phase_cycles: float
    cn0_dbhz: float           # -inf when the signal is off
    pseudorange_m: float
    elevation_deg: float


@dataclass(frozen=True)
class ReceiverTruth:
    t_rx_s: float
    gps_week: int
    gps_tow_s: float
    pos_ecef_m: np.ndarray
    vel_ecef_m_s: np.ndarray
    clock_bias_s: float
    clock_drift_s_s: float
    claimed_ecef_m: np.ndarray | None   # the attacker's claimed position while it transmits
    claimed_delay_s: float | None = None  # the delay common to every spoofed signal while it transmits


class Simulator:
    """Renders a scenario; iterate over chunks() for complex samples in output units (noise RMS per component)."""

    def __init__(self, cfg: dict, motion=None, constellation: Constellation | None = None):
        self.cfg = cfg
        s, c, r = cfg["signal"], cfg["constellation"], cfg["receiver"]
        self.fs_hz, self.if_hz = float(s["fs_hz"]), float(s["if_hz"])
        self.constellation = constellation or build_constellation(cfg)
        self.t0 = self.constellation.start
        self.n_samples = int(round(cfg["time"]["duration_s"] * self.fs_hz))
        self.chunk_samples = int(round(CHUNK_S * self.fs_hz))
        self.noise_rms = s["noise_rms"] or FORMAT_NOISE_RMS[s["format"]]
        self.clock_bias_s, self.clock_drift = r["clock_bias_s"], r["clock_drift_s_s"]
        self.start_pos = geodetic_to_ecef(np.radians(r["lat_deg"]), np.radians(r["lon_deg"]), r["height_m"])
        if motion is None:
            motion = (TrajectoryMotion.from_csv(r["trajectory"], r["trajectory_lla"]) if r["trajectory"]
                      else StaticMotion(self.start_pos))
            self.start_pos = motion.state(0.0)[0][0]
        self.motion = motion
        self.attack = AttackPlan.from_config(cfg["attacker"]) if cfg["attacker"]["enabled"] else None
        self.iono = self.constellation.iono if c["ionosphere"] else None
        self._rng = np.random.default_rng(s["seed"])
        self._first_bit = int(math.floor(self.t0.seconds * NAV_BIT_RATE_HZ))
        self._t0_after_bit_s = self.t0.seconds - self._first_bit / NAV_BIT_RATE_HZ
        self.signals = self._choose_signals()
        self._stack = stack_ephemerides(self.constellation.ephemerides[sig.prn] for sig in self.signals)
        self.clipped = 0

    # -- which signals exist ------------------------------------------------------------------------------
    def _visible(self, pos_ecef_m, prns_wanted) -> list[int]:
        eph = self.constellation.ephemerides
        prns = [p for p in sorted(eph) if not prns_wanted or p in prns_wanted]
        if not prns:
            return []
        arr = arrival(stack_ephemerides(eph[p] for p in prns), pos_ecef_m, np.zeros(3), self.t0.tow_s, None, False)
        mask = np.radians(self.cfg["constellation"]["elevation_mask_deg"])
        order = np.argsort(-arr.elevation_rad)
        return sorted(prns[i] for i in order
                      if arr.elevation_rad[i] > mask)[:self.cfg["constellation"]["max_satellites"]]

    def _choose_signals(self) -> list[_Signal]:
        c = self.constellation
        almanac = c.ephemerides
        rng = np.random.default_rng([self.cfg["signal"]["seed"], 7])
        legit = self._visible(self.start_pos, self.cfg["constellation"]["prns"])
        if not legit:
            raise ValueError("no satellite above the elevation mask at the receiver's position and time")
        signals = [_Signal("legit", p, NavStream(c.ephemerides[p], c.iono, c.utc, almanac), rng.uniform())
                   for p in legit]
        mp = self.cfg["multipath"]
        if mp["enabled"]:
            for sig in list(signals):
                if not mp["prns"] or sig.prn in mp["prns"]:
                    signals.append(replace(sig, source="multipath", phase_offset_cycles=rng.uniform(),
                                           extra_delay_m=mp["delay_chips"] * SPEED_OF_LIGHT_M_S / CA_CHIP_RATE_HZ))
        if self.attack:
            claimed0 = self.attack.claimed_position(0.0, self.start_pos, self.start_pos)
            spoofed = [p for p in self.attack.prns if p in c.ephemerides] if self.attack.prns else \
                self._visible(claimed0, [])
            for p in spoofed:
                eph = c.ephemerides[p]
                if self.attack.altered_clock_s:
                    eph = quantize_ephemeris(replace(eph, af0_s=eph.af0_s + self.attack.altered_clock_s))
                twin = next((s for s in signals if s.prn == p and s.source == "legit"), None)
                phase = twin.phase_offset_cycles if (self.attack.aligned and twin) else rng.uniform()
                nav = NavStream(eph, c.iono, c.utc, almanac)
                signals.append(_Signal("spoof", p, nav, phase))
                a = self.cfg["attacker"]
                for i in range(1, a["copies"]):
                    signals.append(_Signal("spoof", p, nav, rng.uniform(),
                                           extra_delay_m=i * a["copy_spacing_s"] * SPEED_OF_LIGHT_M_S))
        return signals

    # -- one instant ----------------------------------------------------------------------------------------
    def _receiver_state(self, tau_s: float):
        elapsed = tau_s * (1.0 - self.clock_drift)
        pos, vel = self.motion.state(elapsed)
        bias = self.clock_bias_s + self.clock_drift * tau_s
        return pos[0], vel[0], bias, self.t0 + (tau_s - bias)

    def _pseudoranges(self, tau_s: float):
        """Code and carrier pseudoranges (m, receiver clock included), elevations and the receiver's truth."""
        pos, vel, bias, t_gps = self._receiver_state(tau_s)
        code_m, carrier_m = np.empty(len(self.signals)), np.empty(len(self.signals))
        el = np.empty(len(self.signals))
        legit = arrival(self._stack, pos, vel, t_gps.tow_s, self.iono, self.cfg["constellation"]["troposphere"])
        code_m[:], carrier_m[:], el[:] = legit.code_m, legit.carrier_m, legit.elevation_rad
        claimed = None
        if self.attack:
            delay = self.attack.delay_s(tau_s)
            claimed = self.attack.claimed_position(tau_s - delay, pos, self.start_pos)
            spoof = arrival(self._stack, claimed,
                            vel if self.attack.mode in ("push", "takeover", "time_push") else np.zeros(3),
                            t_gps.tow_s - delay, self.iono, self.cfg["constellation"]["troposphere"])
            is_spoof = np.array([s.source == "spoof" for s in self.signals])
            code_m[is_spoof] = spoof.code_m[is_spoof] + SPEED_OF_LIGHT_M_S * delay
            carrier_m[is_spoof] = spoof.carrier_m[is_spoof] + SPEED_OF_LIGHT_M_S * delay
            el[is_spoof] = spoof.elevation_rad[is_spoof]
        extra = np.array([s.extra_delay_m for s in self.signals])
        clock_m = SPEED_OF_LIGHT_M_S * bias
        on = self.attack is not None and self.attack.active(tau_s)
        truth = ReceiverTruth(tau_s, t_gps.week, t_gps.tow_s, pos, vel, bias, self.clock_drift,
                              claimed if on else None, self.attack.delay_s(tau_s) if on else None)
        return code_m + extra + clock_m, carrier_m + extra + clock_m, el, truth

    def _cn0_dbhz(self, tau_s: float, el_rad: np.ndarray) -> np.ndarray:
        c = self.cfg["constellation"]
        cn0 = np.full(len(self.signals), c["cn0_dbhz"])
        if c["cn0_model"] == "elevation":
            cn0 += 8.0 * (np.sin(np.maximum(el_rad, 0.0)) - 1.0)
        cn0[el_rad < np.radians(c["elevation_mask_deg"])] = -np.inf
        for i, sig in enumerate(self.signals):
            if sig.source == "spoof":
                cn0[i] = (c["cn0_dbhz"] + self.attack.advantage_db(tau_s)) if self.attack.active(tau_s) else -np.inf
            elif sig.source == "multipath":
                cn0[i] += self.cfg["multipath"]["relative_power_db"]
        return cn0

    def _phase_cycles(self, tau_s: float, carrier_m: np.ndarray) -> np.ndarray:
        offsets = np.array([s.phase_offset_cycles for s in self.signals])
        spoof_hz = np.array([self.attack.carrier_offset_hz if (self.attack and s.source == "spoof") else 0.0
                             for s in self.signals])
        return -carrier_m / L1_WAVELENGTH_M + (self.if_hz + spoof_hz) * tau_s + offsets

    def _chips(self, tau_s: float, code_m: np.ndarray) -> np.ndarray:
        """Chips since the start of data bit number self._first_bit, per signal."""
        return (self._t0_after_bit_s + tau_s - code_m / SPEED_OF_LIGHT_M_S) * CA_CHIP_RATE_HZ

    # -- the stream -----------------------------------------------------------------------------------------
    def chunks(self, on_truth: Callable[[ReceiverTruth, list[SignalTruth]], None] | None = None,
               truth_every_s: float = 0.1, on_event: Callable[[dict], None] | None = None) -> Iterator[np.ndarray]:
        """Yield complex64 chunks of CHUNK_S; call on_truth every truth_every_s with the state at that sample."""
        fs = self.fs_hz
        amp_per_sqrt_hz = math.sqrt(2.0 * self.noise_rms ** 2 / fs)
        if self.cfg["signal"]["format"] in REAL_FORMATS:
            # the real part is written: it keeps the noise density but half of each signal's power (the other half
            # is its mirror image at -IF), so each amplitude is raised by sqrt(2) to keep the C/N0 asked for
            amp_per_sqrt_hz *= math.sqrt(2.0)
        codes = np.stack([ca_code(s.prn) for s in self.signals])
        truth_every = max(1, int(round(truth_every_s / CHUNK_S)))
        code0, carr0, el0, truth0 = self._pseudoranges(0.0)
        announced: set[str] = set()
        k0, index = 0, 0
        while k0 < self.n_samples:
            n = min(self.chunk_samples, self.n_samples - k0)
            tau0, tau1 = k0 / fs, (k0 + n) / fs
            code1, carr1, el1, truth1 = self._pseudoranges(tau1)
            cn0 = self._cn0_dbhz(tau0, el0)
            amplitude = np.where(np.isfinite(cn0),
                                 amp_per_sqrt_hz * 10.0 ** (np.where(np.isfinite(cn0), cn0, 0) / 20), 0.0)
            chips_a, chips_b = self._chips(tau0, code0), self._chips(tau1, code1)
            ph_a, ph_b = self._phase_cycles(tau0, carr0), self._phase_cycles(tau1, carr1)
            first_bits = np.floor(chips_a / CHIPS_PER_BIT).astype(np.int64)
            n_bits = int(np.max(np.floor(chips_b / CHIPS_PER_BIT).astype(np.int64) - first_bits)) + 2
            bits = np.stack([s.nav.bits(self._first_bit + int(fb), n_bits) for s, fb in zip(self.signals, first_bits)])
            out = (self._rng.standard_normal(2 * n, dtype=np.float32) * np.float32(self.noise_rms)).view(np.complex64)
            render(out, codes, bits, chips_a - first_bits * CHIPS_PER_BIT, (chips_b - chips_a) / n,
                   ph_a - np.floor(ph_a), (ph_b - ph_a) / n, amplitude)
            if on_truth is not None and index % truth_every == 0:
                doppler = -(carr1 - carr0) / (tau1 - tau0) / L1_WAVELENGTH_M
                sig_truth = [SignalTruth(tau0, s.prn, s.source, float(np.mod(chips_a[i], 1023.0)), float(doppler[i]),
                                         float(ph_a[i]), float(cn0[i]), float(code0[i]), float(np.degrees(el0[i])))
                             for i, s in enumerate(self.signals)]
                on_truth(truth0, sig_truth)
            if on_event is not None and self.attack:
                self._attack_events(tau0, announced, on_event)
            yield out
            code0, carr0, el0, truth0 = code1, carr1, el1, truth1
            k0 += n
            index += 1

    def _attack_events(self, tau_s: float, announced: set, on_event) -> None:
        a = self.attack
        phases = [("attack_start", a.start_s),
                  ("drag_off_start",
                   a.start_s + a.push_hold_s if a.mode in ("push", "takeover", "time_push") else None),
                  ("full_power", a.start_s + a.power_ramp_s if a.power_ramp_s > 0 else None)]
        for name, t in phases:
            if t is not None and name not in announced and tau_s >= t:
                announced.add(name)
                on_event({"t_rx_s": round(tau_s, 6), "event": name, "mode": a.mode,
                          "prns": [s.prn for s in self.signals if s.source == "spoof"],
                          "power_advantage_db": a.power_advantage_db,
                          **({"time_push_rate_s_s": a.time_push_rate_s_s} if a.mode == "time_push" else {})})


def make_live_simulator(cfg: dict) -> tuple[Simulator, LiveMotion]:
    """A simulator whose receiver moves as a vehicle model says, chunk by chunk (the closed loop)."""
    r = cfg["receiver"]
    motion = LiveMotion(geodetic_to_ecef(np.radians(r["lat_deg"]), np.radians(r["lon_deg"]), r["height_m"]))
    return Simulator(cfg, motion=motion), motion

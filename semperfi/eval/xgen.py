"""Spoofing recordings from a generator nobody here wrote: GPS-SDR-SIM renders a legitimate scene and a spoofer
scene on the same GPS time (a synchronized attacker), and our own mixer adds them with calibrated noise.

GPS-SDR-SIM (github.com/osqzss/gps-sdr-sim) is called when `gps-sdr-sim` is on PATH; nothing of it is shipped here.
With `-p` it holds every satellite at one fixed gain: each renders I and Q from a +/-250 cosine/sine table times
128 / 2^7, a complex amplitude of 250 per satellite, so C/N0 = 250^2 / N0 and the noise follows from the C/N0 asked
for. Without it (Case.path_loss) each satellite's gain is 128 times its free-space loss (20200 km / range) times
the antenna pattern at its elevation (0 dB at the zenith, -8.9 dB at the horizon): the satellites then span about
11 dB under cn0_dbhz. The mix is int16 IQ (GNSS-SDR's ishort) with a SigMF sidecar, written in bounded memory.

A time push (Case.push_ns_per_s, TEXBAT-like) needs no second scene: the spoofer is the legitimate scene itself,
sample for sample, delayed from push_from_s on by a growing d(t), code and carrier together (delayed_scene).
"""

from __future__ import annotations

import hashlib
import math
import os
import shutil
import subprocess
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pymap3d
from scipy.signal import butter, sosfilt
from scipy.special import i0

from ..errors import BadInput
from ..flight import Leg, ManeuverLimits, plan_trajectory, write_track_csv
from ..iq import build_sigmf_meta, encode_samples, format_by_name, sidecar_path, write_sigmf_meta
from ..receiver import TRUSTED_STATES
from ..sim import gaussian
from .flightpath import MOTION_DT_S, ins_track, write_motion_csv
from .metrics import Truth, fix_errors, gps_time, read_fixes

GPS_SDR_SIM = "gps-sdr-sim"
OURS = "ours"                  # our own simulator (semperfi.eval.ours)
GENERATORS = (GPS_SDR_SIM, OURS)
AMPLITUDE = 250.0           # complex amplitude of one satellite in gps-sdr-sim's 16-bit output with -p
OUTPUT_SCALE = 0.5          # headroom in int16 for a +20 dB spoofer on a dozen satellites
# gps-sdr-sim delays each range by the broadcast (Klobuchar) ionosphere and nothing else (computeRange): no
# troposphere. A receiver that removes one from these recordings is biased by up to ~20 m at 5 deg elevation
# (a 7 m horizontal bias in Boston on 2014-12-20), so the receivers run on them are told the generator's truth.
RECEIVER_SETTINGS = ("pvt.troposphere=false",)
MIX_BLOCK_S = 1.0
# A receiver's front end (Case.front_end_hz): the scenes rendered FRONT_END_UP times faster, the mix through an
# analog-like low-pass (Butterworth, FRONT_END_ORDER) and decimated -- chips rounded as every real recording's are,
# where gps-sdr-sim alone samples ideal rectangular chips at the output rate. The rendering still places each chip's
# edges on its own sample grid, 1/10 chip apart at 4x: a residue of every signal no canceller can model (a real
# front end filters exact edges) -- on a synthetic +10 dB scene behind 1 MHz at 2.6 MSa/s the spoofers were left
# 22.4 dB down rendered 4x faster, 27.9 dB at 16x, while what was left correlating with their codes lay 34-43 dB
# down either way: noise-like, it raises no receiver's floor measurably. 16x is four times the disk (10 GB a scene).
FRONT_END_UP = 4
FRONT_END_ORDER = 5
# A recording's samples (Case.item_type): int16 IQ, as gps-sdr-sim writes; int8 IQ at an AGC's level (the first
# block's RMS, the spoofer's power in it, at INT8_RMS per component: 4 sigma below the clip); or real int16 at an IF,
# a quarter of the rate (behind a front end only: the band-limited mix moved up to IF_SHARE of the rate, its real
# part kept -- both images keep the complex recording's C/N0, at twice its rate)
RECORDING_ITEM_TYPES = ("ishort", "ibyte", "short")
INT8_RMS = 32.0
IF_SHARE = 0.25
F_L1_HZ = 1575.42e6
DELAY_SUB_BLOCK_S = 1e-3     # the time push's delay is held per sub-block (25 ns/s: 25 ps);
                             # its carrier turns per sample
SINC_HALF_TAPS = 16          # the fractional-delay interpolator: a Kaiser-windowed sinc, 2 x 16 taps
SINC_KAISER_BETA = 8.0


class XgenError(BadInput):
    """A problem worth one line to the user."""


@dataclass(frozen=True)
class Place:
    name: str
    lat_deg: float
    lon_deg: float
    height_m: float = 10.0


PLACES = {p.name: p for p in (Place("boston", 42.3398, -71.0892), Place("sydney", -33.8688, 151.2093),
                              Place("zurich", 47.3769, 8.5417), Place("singapore", 1.3521, 103.8198))}
OWN_DATE = "2022/01/01,00:00:00"     # the shared ephemeris' own day (brdc0010.22n)
RINEX_HEADER_END = "END OF HEADER"
SCENES_ENV = "SEMPERFI_SCENES"       # a folder to keep gps-sdr-sim's scenes in across runs (default: work/scenes)


@dataclass(frozen=True)
class Case:
    place: Place
    offset_m: float                  # the claimed position, this far from the truth
    advantage_db: float              # spoofer power over the legitimate signals
    date: str = OWN_DATE             # gps-sdr-sim's start time, on the day of the ephemeris file (ephemeris_day)
    azimuth_deg: float = 90.0        # direction of the claimed position (east)
    duration_s: float = 40.0
    fs_hz: float = 2.6e6
    cn0_dbhz: float = 45.0
    spoof_start_s: float = 0.0
    seed: int = 1
    attacker: bool = True            # False: the legitimate scene and noise only
    motion: str = ""                 # the receiver's 10 Hz trajectory (gps-sdr-sim -u: t,x,y,z ECEF); empty: static
    spoof_motion: str = ""           # the spoofer's claimed trajectory instead of a static claimed place (takeover)
    path_loss: bool = False          # gps-sdr-sim's own path loss and antenna pattern per satellite (no -p)
    push_ns_per_s: float = 0.0       # not 0: a time push, the spoofer the legitimate scene delayed at this rate
    push_from_s: float = 0.0         # ... from this time on (identical to it before)
    takeover_hold_s: float = 0.0     # a takeover's (spoof_motion's) parameters, for a generator that takes them
    takeover_m_s: float = 0.0        # rather than a claimed trajectory
    generator: str = GPS_SDR_SIM     # what renders the scenes: gps-sdr-sim, or ours (semperfi.eval.ours)
    front_end_hz: float = 0.0        # not 0: a front end's low-pass cutoff (one-sided), FRONT_END_UP
    item_type: str = "ishort"        # the recording's samples (RECORDING_ITEM_TYPES, GNSS-SDR's names)

    @property
    def real(self) -> bool:
        """Real samples at an IF (fs_hz is then their rate, twice the complex band's)."""
        return not format_by_name(self.item_type).is_complex

    @property
    def if_hz(self) -> float:
        return IF_SHARE * self.fs_hz if self.real else 0.0

    @property
    def _when(self) -> str:
        day, clock = self.date.split(",")
        return day.replace("/", "") + ("" if clock == "00:00:00" else "T" + clock.replace(":", ""))

    @property
    def _power(self) -> str:
        return ("-pl" if self.path_loss else "") + ("" if self.cn0_dbhz == 45.0 else f"-{self.cn0_dbhz:g}dBHz")

    @property
    def _length(self) -> str:
        mark = "" if self.generator == GPS_SDR_SIM else f"-{self.generator}"
        front = f"-fe{self.front_end_hz / 1e6:g}M" if self.front_end_hz else ""
        samples = "" if self.item_type == "ishort" else f"-{self.item_type}"
        return f"{self.fs_hz / 1e6:g}M{front}{samples}-{self.duration_s:g}s-s{self.seed}{mark}"

    @property
    def scene(self) -> str:
        """What names the legitimate scene and its noise: the same for a case and its clean twin."""
        trip = "-" + Path(self.motion).stem if self.motion else ""
        return f"{self.place.name}-{self._when}{trip}{self._power}-{self._length}"

    @property
    def tag(self) -> str:
        bearing = "" if self.azimuth_deg == 90.0 else f"-{self.azimuth_deg:g}deg"
        attack = f"{self.offset_m:g}m{bearing}-{self.advantage_db:+g}dB" if self.attacker else "clean"
        if self.attacker and self.spoof_start_s:
            attack += f"-from{self.spoof_start_s:g}s"
        if self.motion:
            attack += "-" + Path(self.motion).stem
        if self.attacker and self.spoof_motion:
            attack = f"{Path(self.spoof_motion).stem}-{self.advantage_db:+g}dB"
        if self.attacker and self.push_ns_per_s:
            attack = f"push{self.push_ns_per_s:g}nsps-from{self.push_from_s:g}s-{self.advantage_db:+g}dB"
        return f"{self.place.name}-{self._when}-{attack}{self._power}-{self._length}"

    @property
    def clean(self) -> Case:
        """The same legitimate scene and noise without the attacker."""
        return replace(self, attacker=False, offset_m=0.0, advantage_db=0.0, spoof_motion="", spoof_start_s=0.0,
                       push_ns_per_s=0.0, push_from_s=0.0, takeover_hold_s=0.0, takeover_m_s=0.0)

    @property
    def truth(self) -> Truth:
        """The receiver's true place (and motion) and the GPS time of the first sample."""
        return Truth(self.place.lat_deg, self.place.lon_deg, self.place.height_m, self.motion, gps_time(self.date))


def gps_sdr_sim_path() -> str | None:
    """gps-sdr-sim on PATH, else the one built for this machine in the shared folder beside a checkout."""
    beside = Path(__file__).resolve().parents[3] / "shared" / "bin" / GPS_SDR_SIM
    return shutil.which(GPS_SDR_SIM) or (str(beside) if beside.is_file() else None)


def ephemeris_day(nav_path: str | Path) -> str:
    """gps-sdr-sim's start time for a RINEX 2 GPS navigation file: midnight of its first record's day."""
    lines = Path(nav_path).read_text(errors="replace").splitlines()
    try:
        first = lines[next(i for i, line in enumerate(lines) if RINEX_HEADER_END in line) + 1]
        yy, mm, dd = (int(v) for v in first[2:22].split()[:3])
    except (StopIteration, IndexError, ValueError):
        raise XgenError(f"{nav_path}: not a RINEX 2 GPS navigation file") from None
    return f"{2000 + yy if yy < 80 else 1900 + yy:04d}/{mm:02d}/{dd:02d},00:00:00"


def claimed_place(case: Case) -> Place:
    """The spoofer's claimed position: offset_m along azimuth_deg on the local horizon."""
    az = math.radians(case.azimuth_deg)
    lat, lon, h = pymap3d.enu2geodetic(case.offset_m * math.sin(az), case.offset_m * math.cos(az), 0.0,
                                       case.place.lat_deg, case.place.lon_deg, case.place.height_m)
    return Place(f"{case.place.name}-claimed", float(lat), float(lon), float(h))


def recording_s(case: Case) -> float:
    """The length of a case's recording: gps-sdr-sim renders duration_s in 0.1 s blocks but one (its loop runs
    from the second time step)."""
    return (int(round(case.duration_s * 10)) - 1) / 10.0


def scene_bytes(case: Case) -> int:
    """The bytes of a case's scene: gps-sdr-sim's 16-bit IQ over recording_s."""
    return 4 * int(round(case.fs_hz * 0.1)) * int(round(recording_s(case) * 10))


def scene_samples(scene: Path, case: Case) -> np.ndarray:
    """A scene's interleaved int16 IQ for a case (a memmap): the first scene_bytes of a file that may be longer."""
    return np.memmap(scene, dtype=np.int16, mode="r", shape=(scene_bytes(case) // 2,))


def render(nav_path: str | Path, out: Path, place: Place, case: Case, motion: str = "") -> Path:
    """One gps-sdr-sim scene (16-bit IQ, fixed gain or, with case.path_loss, gps-sdr-sim's path loss and antenna
    pattern), static at a place or along a motion file. Cached: a file at least as long is reused (gps-sdr-sim's
    output for a longer duration begins with the shorter one's, byte for byte), and a scene is written under another
    name and then renamed, so that runs sharing the folder never read one half written."""
    exe = gps_sdr_sim_path()
    if exe is None:
        raise XgenError(f"{GPS_SDR_SIM} not found on PATH (build it from github.com/osqzss/gps-sdr-sim: one gcc line)")
    if out.is_file() and out.stat().st_size >= scene_bytes(case):
        return out
    # gps-sdr-sim keeps file names in 100-character buffers: it runs in the output's folder, on short names
    tag = f"{os.getpid()}-{time.monotonic_ns()}"
    nav = out.parent / f"{Path(nav_path).name}.{tag}"
    shutil.copyfile(nav_path, nav)
    track = out.parent / f"motion.{tag}.csv"
    if motion:
        shutil.copyfile(motion, track)
    part = out.parent / f"{out.stem}.{tag}.part"
    where = ["-u", track.name] if motion else ["-l", f"{place.lat_deg:.9f},{place.lon_deg:.9f},{place.height_m:.3f}"]
    args = [exe, "-e", nav.name, *where,
            "-s", f"{case.fs_hz:.0f}", "-d", f"{case.duration_s:g}", "-b", "16", *([] if case.path_loss else ["-p"]),
            "-o", part.name,
            "-t", case.date]
    try:
        r = subprocess.run(args, capture_output=True, text=True, timeout=3600, cwd=out.parent)
        if r.returncode != 0 or not part.is_file():
            raise XgenError(f"gps-sdr-sim failed ({r.returncode}): {(r.stderr or r.stdout).strip().splitlines()[-1:]}")
        os.replace(part, out)
    finally:
        for f in (nav, track, part):
            f.unlink(missing_ok=True)
    return out


def flown_path(duration_s: float, speed_m_s: float = 0.0, heading_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, ned_m (n, 3)) at 10 Hz: a straight flight at a constant speed (0: a static receiver)."""
    t_s = np.arange(int(round(duration_s * 10)) + 1) / 10.0
    h = math.radians(heading_deg)
    return t_s, np.column_stack([speed_m_s * t_s * math.cos(h), speed_m_s * t_s * math.sin(h), np.zeros_like(t_s)])


def takeover_motion(place: Place, hold_s: float, speed_m_s: float, duration_s: float, out: Path,
                    azimuth_deg: float = 90.0, receiver_ned: np.ndarray | None = None) -> Path:
    """A seamless takeover's claimed trajectory (gps-sdr-sim -u, 10 Hz ECEF rows): the receiver's own path (static,
    or receiver_ned from flown_path) for hold_s -- the spoofer's scene is then the legitimate one, sample for sample --
    then pushed off it along azimuth_deg at speed_m_s (a dynamic position push when the receiver moves)."""
    t_s, ned = flown_path(duration_s)
    if receiver_ned is not None:
        ned = ned + receiver_ned
    along = speed_m_s * np.clip(t_s - hold_s, 0.0, None)
    az = math.radians(azimuth_deg)
    ned = ned + np.column_stack([along * math.cos(az), along * math.sin(az), np.zeros_like(t_s)])
    return write_motion_csv(out, t_s, ned, place.lat_deg, place.lon_deg, place.height_m)


def takeover_case(place: Place, hold_s: float, push_m_s: float, duration_s: float, work: Path,
                  advantage_db: float = 3.0, date: str = OWN_DATE, fs_hz: float = 2.6e6, receiver_m_s: float = 0.0,
                  seed: int = 7, path_loss: bool = False, cn0_dbhz: float = 45.0) -> tuple[Case, Path]:
    """A takeover (receiver_m_s 0) or a dynamic push (the receiver flies north at receiver_m_s) pushed east, and the
    INS track of the receiver's flight (a MEMS unit's drift, seeded) for `semperfi run --imu`."""
    t_s, ned = flown_path(duration_s, receiver_m_s)
    stem = f"{hold_s:g}s-{push_m_s:g}mps-{duration_s:g}s" + (f"-fly{receiver_m_s:g}mps" if receiver_m_s else "")
    motion = write_motion_csv(work / f"fly-{receiver_m_s:g}mps-{duration_s:g}s.csv", t_s, ned, place.lat_deg,
                              place.lon_deg, place.height_m) if receiver_m_s else None
    spoof = takeover_motion(place, hold_s, push_m_s, duration_s, work / f"takeover-{stem}.csv",
                            receiver_ned=ned if receiver_m_s else None)
    case = Case(place, 0.0, advantage_db, date=date, fs_hz=fs_hz, duration_s=duration_s,
                motion=str(motion) if motion else "", spoof_motion=str(spoof), path_loss=path_loss, cn0_dbhz=cn0_dbhz,
                takeover_hold_s=hold_s, takeover_m_s=push_m_s)
    ins = write_track_csv(work / f"ins-{case.tag}.csv", t_s, ins_track(t_s, ned, seed=seed, accel_bias_mps2=0.002))
    return case, ins


# a maneuver within the paper's constraints: 47.9 m flown in 17.9 s at up to 3.5 m/s, turning twice, ending 34 m
# from its start, under a gentle acceleration limit
MANEUVER_LEGS = (Leg(3.5, 0.5, 0.0, 5.5), Leg(0.5, 3.5, 0.0, 5.0), Leg(-1.5, 3.0, 0.0, 4.0))
MANEUVER_ACCEL_MPS2 = 1.0


def maneuver_case(place: Place, offset_m: float, advantage_db: float, work: Path, maneuver_at_s: float = 50.0,
                  duration_s: float = 100.0, date: str = OWN_DATE, fs_hz: float = 2.6e6, seed: int = 7,
                  path_loss: bool = False, cn0_dbhz: float = 45.0, legs=MANEUVER_LEGS) -> tuple[Case, Path]:
    """A flying receiver that hovers, flies the legs from maneuver_at_s (smoothly: MANEUVER_ACCEL_MPS2) and hovers
    again to duration_s, under a static spoofer offset_m east from the first sample; and its INS track (a MEMS
    unit's drift, seeded) for `semperfi run --imu`."""
    _, north, east, down = plan_trajectory(legs, ManeuverLimits(dt_s=MOTION_DT_S, max_accel_mps2=MANEUVER_ACCEL_MPS2))
    path = np.column_stack([north, east, down])
    n = int(round(duration_s / MOTION_DT_S)) + 1
    before = int(round(maneuver_at_s / MOTION_DT_S))
    if before + len(path) > n:
        raise XgenError(f"the maneuver ({len(path) * MOTION_DT_S:g} s from {maneuver_at_s:g} s) outlasts "
                        f"{duration_s:g} s")
    ned = np.vstack([np.zeros((before, 3)), path, np.repeat(path[-1:], n - before - len(path), axis=0)])
    t_s = np.arange(n) * MOTION_DT_S
    motion = write_motion_csv(work / f"{place.name}-hover{maneuver_at_s:g}s-maneuver-{duration_s:g}s.csv", t_s, ned,
                              place.lat_deg, place.lon_deg, place.height_m)
    case = Case(place, offset_m, advantage_db, date=date, fs_hz=fs_hz, duration_s=duration_s, motion=str(motion),
                path_loss=path_loss, cn0_dbhz=cn0_dbhz)
    ins = write_track_csv(work / f"ins-{case.tag}.csv", t_s, ins_track(t_s, ned, seed=seed))
    return case, ins


def noise_sigma(fs_hz: float, cn0_dbhz: float) -> float:
    """Per-component noise so that one gps-sdr-sim satellite (complex amplitude AMPLITUDE) sits at cn0_dbhz."""
    return math.sqrt(AMPLITUDE ** 2 * fs_hz / (2.0 * 10 ** (cn0_dbhz / 10.0)))


def _kaiser_sinc(mu: float, half: int = SINC_HALF_TAPS, beta: float = SINC_KAISER_BETA) -> np.ndarray:
    """The 2*half taps h[j] (delays k = j - half + 1) of a fractional delay by mu samples (0 <= mu < 1): a sinc
    under a Kaiser window centred on mu, normalised to unit gain at 0 Hz."""
    x = np.arange(-half + 1, half + 1) - mu
    h = np.sinc(x) * i0(beta * np.sqrt(np.clip(1.0 - (x / half) ** 2, 0.0, None))) / i0(beta)
    return h / h.sum()


def delayed_scene(read, n0: int, n: int, fs_hz: float, delay_s, sub_block_s: float = DELAY_SUB_BLOCK_S,
                  half: int = SINC_HALF_TAPS) -> np.ndarray:
    """Samples n0 .. n0+n-1 of x(t - d(t)) exp(-j 2 pi f_L1 d(t)): the scene x delayed by d(t) at radio frequency
    (code and carrier together), read(a, b) giving x's complex samples a .. b-1 (zeros outside the scene) and
    delay_s(t) the delay in seconds at times t (s, from the first sample). The delay is held per sub-block (a
    windowed-sinc FIR, band-limited, reading what it needs around the block: no state, bounded memory); the carrier
    turns with d(t) sample by sample."""
    t = (n0 + np.arange(n)) / fs_hz
    d = np.asarray(delay_s(t), dtype=float)
    if not d.any():
        return read(n0, n0 + n)
    re, im = np.empty(n), np.empty(n)
    m = max(1, int(round(sub_block_s * fs_hz)))
    for s in range(0, n, m):
        e = min(n, s + m)
        delay = float(d[(s + e - 1) // 2]) * fs_hz
        whole = math.floor(delay)
        h = _kaiser_sinc(delay - whole, half)
        lo = n0 + s - whole - half
        x = read(lo, lo + (e - s) + 2 * half - 1)
        re[s:e] = np.convolve(x.real, h, mode="valid")     # real taps: two real convolutions
        im[s:e] = np.convolve(x.imag, h, mode="valid")
    return (re + 1j * im) * np.exp(-2j * np.pi * F_L1_HZ * d)


def scene_reader(samples: np.ndarray):
    """read(a, b) for delayed_scene over interleaved int16 IQ (a memmap): complex samples a .. b-1, zeros outside."""
    total = samples.size // 2

    def read(a: int, b: int) -> np.ndarray:
        out = np.zeros(b - a, dtype=np.complex128)
        lo, hi = max(a, 0), min(b, total)
        if hi > lo:
            iq = samples[2 * lo:2 * hi].astype(np.float64)
            out[lo - a:hi - a] = iq[0::2] + 1j * iq[1::2]
        return out
    return read


def push_delay(case: Case):
    """The time push's delay d(t) in seconds: push_ns_per_s per second from push_from_s, 0 before."""
    return lambda t: case.push_ns_per_s * 1e-9 * np.clip(np.asarray(t) - case.push_from_s, 0.0, None)


def rendered(case: Case) -> Case:
    """The case its scenes are rendered at (complex): FRONT_END_UP times the complex band's rate behind a front end
    (a real recording's complex band: half its rate)."""
    if case.real and not case.front_end_hz:
        raise XgenError(f"real samples ({case.item_type}) at an IF are made behind a front end: give its cutoff")
    if case.item_type not in RECORDING_ITEM_TYPES:
        raise XgenError(f"recordings are written as {', '.join(RECORDING_ITEM_TYPES)}, not {case.item_type!r}")
    band_hz = case.fs_hz / 2 if case.real else case.fs_hz
    return replace(case, fs_hz=band_hz * FRONT_END_UP, front_end_hz=0.0, item_type="ishort") \
        if case.front_end_hz else case


def mix(legit: Path, spoof: Path | None, out: Path, case: Case) -> Path:
    """legit + spoofer x 10^(P/20) (from spoof_start_s) + white Gaussian noise at the case's C/N0, in the case's
    item_type. With a time push (case.push_ns_per_s) the spoofer is the legitimate scene delayed by push_delay (spoof
    is ignored). Behind a front end (case.front_end_hz) the scenes are at rendered(case)'s rate and the sum is
    filtered (moved to the IF for real samples) and decimated to the case's."""
    fast = rendered(case)
    sigma = noise_sigma(fast.fs_hz, case.cn0_dbhz)
    gain = 10 ** (case.advantage_db / 20.0)
    rng = np.random.default_rng(case.seed)
    a = scene_samples(legit, fast)
    pushed = case.attacker and bool(case.push_ns_per_s)
    b = None if pushed or spoof is None else scene_samples(spoof, fast)
    read, delay = (scene_reader(a), push_delay(fast)) if pushed else (None, None)
    up = int(round(fast.fs_hz / case.fs_hz))
    front_end = FrontEnd(case.front_end_hz, fast.fs_hz, up, case.if_hz) if case.front_end_hz else None
    fmt = format_by_name(case.item_type)
    block = 2 * up * int(round(case.fs_hz * MIX_BLOCK_S))
    start = 2 * int(round(case.spoof_start_s * fast.fs_hz))
    # single precision: int16 scenes, even +20 dB over, keep a thousandth of a unit before the rounding
    gain32, sigma32 = np.float32(gain), np.float32(sigma)
    scale32 = OUTPUT_SCALE if fmt.item_dtype.itemsize > 1 else None   # int8: the AGC settles on the first block
    with open(out, "wb") as f:
        for i in range(0, a.size, block):
            x = a[i:i + block].astype(np.float32)
            if (b is not None or pushed) and i + x.size > start:
                if pushed:
                    z = delayed_scene(read, i // 2, x.size // 2, fast.fs_hz, delay)
                    s = np.column_stack([z.real, z.imag]).ravel().astype(np.float32)
                else:
                    s = b[i:i + block].astype(np.float32)
                s[:max(0, start - i)] = 0.0
                s *= gain32
                x += s
            noise = gaussian(rng, x.size)
            noise *= sigma32
            x += noise
            if front_end is not None:
                x = front_end.filter(x)
            if scale32 is None:
                scale32 = INT8_RMS / math.sqrt(float(np.mean(np.square(x, dtype=np.float64))))
            items, _ = encode_samples(x.view(np.complex64), fmt, scale32)
            f.write(items.tobytes())
    meta = build_sigmf_meta(datatype=fmt.sigmf_datatype, sample_rate_hz=case.fs_hz, if_hz=case.if_hz,
                            dataset=out.name,
                            description=f"gps-sdr-sim legitimate + spoofer scenes mixed by semperfi.eval.xgen: {case}")
    write_sigmf_meta(sidecar_path(out), meta)
    return out


class FrontEnd:
    """A front end's low-pass and decimation over a stream of interleaved IQ blocks (the filter's state carried),
    the band moved up to if_hz before the decimation (a real recording's I is then the signal at that IF). A cutoff
    of 0: no low-pass (ideal chips, decimated as they are)."""

    def __init__(self, cutoff_hz: float, fs_hz: float, down: int, if_hz: float = 0.0):
        self.sos = butter(FRONT_END_ORDER, cutoff_hz, fs=fs_hz, output="sos") if cutoff_hz else None
        self.state = None if self.sos is None else np.zeros((self.sos.shape[0], 2), dtype=np.complex128)
        self.down = down
        self.if_cycles_per_sample = if_hz / fs_hz
        self.n = 0                    # fast samples filtered so far (the IF's phase)

    def filter(self, iq: np.ndarray) -> np.ndarray:
        """Interleaved float IQ in (a whole number of output samples), interleaved float32 IQ out, decimated."""
        z = iq[0::2] + 1j * iq[1::2]
        if self.sos is not None:
            z, self.state = sosfilt(self.sos, z, zi=self.state)
        if self.if_cycles_per_sample:
            k = self.n + np.arange(z.size, dtype=np.int64)
            z *= np.exp(2j * np.pi * ((k * self.if_cycles_per_sample) % 1.0))
        self.n += z.size
        z = z[::self.down]
        return np.column_stack([z.real, z.imag]).ravel().astype(np.float32)


def score(fixes_csv: Path, place: Place, last_s: float = 10.0, bad_m: float = 10.0, motion: str = "") -> dict:
    """What a receiver made of a case: horizontal error over the last seconds, first fix, wrong fixes called good,
    and the mean east and north deviation (absolute) of the fixes called good while under attack (the paper's UTM
    figure: recovered against legitimate path). With a motion file the truth is the trajectory at each fix's time
    (10 Hz rows, interpolated). The issue-22 grid's fuller figures are semperfi.eval.metrics.run_metrics."""
    f = read_fixes(fixes_csv)
    if not f or not f["t_rx_s"].size:
        return {"fixes": 0}
    t = f["t_rx_s"]
    e = fix_errors(f, Truth(place.lat_deg, place.lon_deg, place.height_m, motion))
    east, north, err = e.east_m, e.north_m, e.horizontal_m
    states = f["state"].astype(str) if "state" in f else np.full(t.size, "nominal")
    last = t >= t[-1] - last_s
    good = np.isin(states, TRUSTED_STATES)
    defended = np.isin(states, ("recovered", "rectified"))
    out = {"fixes": int(t.size), "first_fix_s": round(float(t[0]), 1),
           "last_mean_m": round(float(np.mean(err[last])), 2), "max_m": round(float(np.max(err)), 1),
           "last_state": str(states[-1]), "recovered": int(np.sum(states == "recovered")),
           "rectified": int(np.sum(states == "rectified")),
           "called_good_but_wrong": int(np.sum(good & (err > bad_m)))}
    if defended.any():
        out |= {"recovered_from_s": round(float(t[defended][0]), 1),
                "recovered_east_m": round(float(np.mean(np.abs(east[defended]))), 2),
                "recovered_north_m": round(float(np.mean(np.abs(north[defended]))), 2)}
    return out


def scene_dir(work: Path) -> Path:
    """Where a run's scenes are kept: SCENES_ENV's folder when set (shared by runs, a test suite's workers too), else
    work/scenes."""
    d = Path(os.environ.get(SCENES_ENV) or Path(work) / "scenes")
    d.mkdir(parents=True, exist_ok=True)
    return d


def scenes(case: Case, nav_path: str | Path, work: Path) -> tuple[Path, Path | None]:
    """The legitimate scene of a case and its spoofer's (None: no attacker, or a time push, which the mixer makes
    from the legitimate scene), rendered once and cached in scene_dir, named by what renders them: navigation file,
    place or motion (by its content), start time, path loss and rate; a longer one serves a shorter case. Behind a
    front end, at rendered(case)'s rate."""
    case = rendered(case)
    cache = scene_dir(work)
    stem = (f"{Path(nav_path).stem}-{case.date.replace('/', '').replace(',', 'T').replace(':', '')}"
            f"-{case.fs_hz / 1e6:g}M{'-pl' if case.path_loss else ''}")
    legit = render(nav_path, cache / f"{case.place.name}{_trip(case.motion)}-{stem}.bin", case.place, case,
                   case.motion)
    spoof = None
    if case.attacker and case.push_ns_per_s:
        pass                          # the legitimate scene itself, delayed in the mixer
    elif case.attacker and case.spoof_motion:
        spoof = render(nav_path, cache / f"{case.place.name}{_trip(case.spoof_motion)}-{stem}.bin", case.place,
                       case, case.spoof_motion)
    elif case.attacker:
        claimed = claimed_place(case)
        spoof = render(nav_path, cache / f"{case.place.name}-{case.offset_m:g}m-{case.azimuth_deg:g}deg-{stem}.bin",
                       claimed, case)
    return legit, spoof


def disk_bytes(case: Case) -> int:
    """What a case's files take on disk at most: its two scenes at the rate they are rendered, and three recordings
    in its own format (the mix, the scene without the attacker, a cleaned copy)."""
    fast = rendered(case)
    scene = fast.fs_hz * fast.duration_s * format_by_name(fast.item_type).bytes_per_sample
    recording = case.fs_hz * case.duration_s * format_by_name(case.item_type).bytes_per_sample
    return int(2 * scene + 3 * recording)


def _trip(motion: str) -> str:
    """A motion file's part of a scene's name: its content's digest (a longer trip is another file, another name)."""
    return f"-{hashlib.sha256(Path(motion).read_bytes()).hexdigest()[:16]}" if motion else ""


def prepare(case: Case, nav_path: str | Path | None, work: Path) -> Path:
    """The mixed recording of a case: its scenes from `scenes` mixed here, or rendered whole by our own simulator
    (semperfi.eval.ours; without a navigation file, on its synthesized constellation)."""
    if case.generator != GPS_SDR_SIM:
        from .ours import render_case
        return render_case(case, nav_path, work / f"{case.tag}.bin")
    if nav_path is None:
        raise XgenError("gps-sdr-sim needs a RINEX navigation file (--nav)")
    work.mkdir(parents=True, exist_ok=True)
    return mix(*scenes(case, nav_path, work), work / f"{case.tag}.bin", case)


def run_case(case: Case, nav_path: str | Path, work: Path, defense: str = "full", assisted: bool = True,
             imu_csv: str | Path | None = None, sets: tuple[str, ...] = (), until_first_fix: bool = False) -> dict:
    """Prepare a case, run `semperfi run` on it in-process (with --imu TRACK.csv when given, and --set for each of
    sets), and score it. A receiver that raises does not stop the caller: its one-line error is the result's
    "crash" (None when it ran through), scored on what it wrote. until_first_fix stops the run at its first fix
    (a clean run for the time to first fix). The result also says where the outputs are ("out") and the
    receiver's wall time."""
    import functools

    from ..defense import load_config
    from ..defense import DefendedReceiver
    from ..defense import read_imu_csv
    from ..receiver import NoSignal, run_file
    data = prepare(case, nav_path, work)
    variant = "".join("-" + s.replace('"', "").replace("=", "-") for s in sets)
    out = work / f"{case.tag}-{defense}{'' if assisted else '-unassisted'}{'-imu' if imu_csv else ''}{variant}"
    receiver = functools.partial(DefendedReceiver, imu_track=read_imu_csv(imu_csv) if imu_csv else None)
    cfg = load_config(None, [f'defense.mode="{defense}"', *RECEIVER_SETTINGS, *sets])
    crash = None
    t0 = time.perf_counter()
    try:
        summary = run_file(data, None, None, None, cfg, out, str(nav_path) if assisted and nav_path else None,
                           receiver_factory=receiver,
                           stop=(lambda rx: rx.last_fix is not None) if until_first_fix else None)
        crash = summary.internal_error
    except NoSignal:                  # no fix at all, which the score says
        pass
    except Exception as exc:          # noqa: BLE001 -- a receiver's crash is a result, recorded
        crash = one_line(exc)
    wall_s = round(time.perf_counter() - t0, 1)
    return {"case": case.tag, "defense": defense, "assisted": assisted, "crash": crash, "wall_s": wall_s,
            "out": str(out), **score(out / "fixes.csv", case.place, motion=case.motion)}


def one_line(exc: BaseException) -> str:
    """An exception as one line: its type and its message's first line."""
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text.splitlines()[0]}" if text else type(exc).__name__


def plugin_case(case: Case, nav_path: str | Path, work: Path, timeout_s: float = 1800.0) -> dict:
    """The plug-in claim on a case: `semperfi clean` on the mix, then GNSS-SDR, unmodified, on the cleaned file
    (troposphere off, as in the scenes); GNSS-SDR's horizontal error over its last 10 s and at most."""
    from ..defense import load_config
    from ..defense import clean_file
    from .gnss_sdr import horizontal_errors_m, run_gnss_sdr
    data = prepare(case, nav_path, work)
    cleaned = work / f"{case.tag}-clean.bin"
    summary = clean_file(data, cleaned, format_by_name(case.item_type), case.fs_hz, case.if_hz,
                         load_config(None, ['defense.mode="full"']))
    try:
        fixes = run_gnss_sdr(cleaned, case.fs_hz, case.item_type, case.if_hz, work / f"{case.tag}-gnss-sdr",
                             timeout_s, trop_model="OFF")
    finally:
        cleaned.unlink(missing_ok=True)
        sidecar_path(cleaned).unlink(missing_ok=True)
    out = {"case": case.tag, "receiver": "gnss-sdr on semperfi clean", "cancelled": list(summary.cancelled),
           "fixes": len(fixes)}
    if fixes:
        err = horizontal_errors_m(fixes, case.place.lat_deg, case.place.lon_deg)
        t_s = np.array([f.t_sod_s for f in fixes])
        last = t_s >= t_s[-1] - 10.0
        out.update(last_mean_m=round(float(np.mean(err[last])), 2), mean_m=round(float(np.mean(err)), 2),
                   max_m=round(float(np.max(err)), 1))
    return out

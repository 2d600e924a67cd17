"""What an unmodified receiver sees on the plug-in filter's output, per PRN (issue 25).

The same legitimate scene with the same noise is received twice by the same receiver: once as it is (the reference:
no attacker at all) and once attacked and then cleaned by `semperfi clean`. Per epoch, the difference of the two
pseudoranges of a PRN less the epoch's median over PRNs (the two runs' clocks) is what the cleaning did to that
PRN's range: a bias of metres is a twin distorted by the subtraction or by the spoofer's residue, tens of metres or
more is a PRN tracked on what is left of the spoofer, a PRN missing is one the filter took away or the receiver lost.
Its C/N0 against the reference says how much of the legitimate signal the cancellation took with it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..gps import GPS_EPOCH

SPOOFED_M = 150.0           # a range this far from the reference's (half a chip) is not the twin's at all


@dataclass(frozen=True)
class Ranges:
    """One receiver's observations of one PRN: GPS seconds since the GPS epoch, pseudorange (m), C/N0 (dB-Hz)."""
    t_s: np.ndarray
    range_m: np.ndarray
    cn0_dbhz: np.ndarray


def read_ranges(rinex_path: str | Path) -> dict[int, Ranges]:
    """C1C and S1C per GPS PRN from a RINEX observation file (ours or GNSS-SDR's), read with georinex."""
    import georinex
    with warnings.catch_warnings():   # georinex's xarray.concat warns of a future default per epoch: not ours to act on
        warnings.simplefilter("ignore", FutureWarning)
        obs = georinex.load(str(rinex_path), use="G", meas=["C1C", "S1C"], fast=False)
    if obs.time.size == 0:             # a receiver that never had an observation writes only the header
        return {}
    t_s = (obs.time.values - np.datetime64(GPS_EPOCH.replace(tzinfo=None))) / np.timedelta64(1, "ns") * 1e-9
    out = {}
    for sv in obs.sv.values:
        pr = obs["C1C"].sel(sv=sv).values.astype(float)
        cn0 = obs["S1C"].sel(sv=sv).values.astype(float) if "S1C" in obs else np.full(pr.shape, np.nan)
        ok = np.isfinite(pr) & (pr > 0)
        if ok.any():
            out[int(str(sv)[1:])] = Ranges(t_s[ok], pr[ok], cn0[ok])
    return out


def _epoch_keys(t_s: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t_s) * 100.0).astype(np.int64)      # 10 ms: both runs' epochs on one grid


def range_differences(reference: dict[int, Ranges], test: dict[int, Ranges], from_s: float | None = None
                      ) -> dict[int, dict]:
    """Per PRN of either run: its range in `test` less its range in `reference` at the same epoch, less the epoch's
    median over the PRNs both have (the clocks), from GPS second from_s on (None: every common epoch).

    Each PRN's entry: epochs compared, mean, standard deviation and worst absolute difference (m), and the mean C/N0
    in each run; `status` is 'absent' (in the reference only), 'extra' (in the test only), 'spoofed' (mean beyond
    SPOOFED_M) or 'twin'. A receiver's time tag may differ by its clock offset between runs: the epochs of the two
    are matched on a 10 ms grid, so each must tag its epochs within a few ms of the other's."""
    keys = {}
    for name, obs in (("ref", reference), ("test", test)):
        for prn, r in obs.items():
            sel = np.ones(r.t_s.size, bool) if from_s is None else r.t_s >= from_s
            keys[(name, prn)] = dict(zip(_epoch_keys(r.t_s[sel]), zip(r.range_m[sel], r.cn0_dbhz[sel])))
    epochs = sorted(set().union(*[set(k) for (name, _), k in keys.items() if name == "test"])
                    & set().union(*[set(k) for (name, _), k in keys.items() if name == "ref"])) \
        if keys else []
    prns = sorted({prn for _, prn in keys})
    diffs: dict[int, list[float]] = {p: [] for p in prns}
    for e in epochs:
        d = {p: keys[("test", p)][e][0] - keys[("ref", p)][e][0] for p in prns
             if e in keys.get(("test", p), {}) and e in keys.get(("ref", p), {})}
        if len(d) < 2:
            continue
        common = float(np.median(list(d.values())))
        for p, v in d.items():
            diffs[p].append(v - common)
    out = {}
    for p in prns:
        ref, test_ = keys.get(("ref", p), {}), keys.get(("test", p), {})
        entry = {"cn0_ref_dbhz": _mean_cn0(ref), "cn0_test_dbhz": _mean_cn0(test_)}
        v = np.array(diffs[p])
        if v.size:
            entry |= {"epochs": int(v.size), "mean_m": round(float(np.mean(v)), 2), "std_m": round(float(np.std(v)), 2),
                      "worst_m": round(float(np.max(np.abs(v))), 2),
                      "status": "spoofed" if abs(np.mean(v)) > SPOOFED_M else "twin"}
        else:
            entry |= {"epochs": 0, "status": "absent" if ref and not test_ else "extra" if test_ and not ref
                      else "apart"}
        out[p] = entry
    return out


def _mean_cn0(rows: dict) -> float | None:
    cn0 = np.array([c for _, c in rows.values()], dtype=float)
    cn0 = cn0[np.isfinite(cn0)]
    return round(float(np.mean(cn0)), 1) if cn0.size else None


def fingerprint(case, nav_path: str | Path, work: Path, gnss_sdr: bool = True, from_s: float = 0.0,
                gnss_sdr_runs: int = 1, gnss_sdr_dwells: int = 1) -> dict:
    """Clean a case's mix and receive it, and the same scene without an attacker, with our receiver (--defense off)
    and, when asked and on PATH, GNSS-SDR (unmodified, RINEX on): per receiver, per PRN, range_differences (from
    from_s seconds into the recording), and what `clean` said it did. GNSS-SDR runs gnss_sdr_runs times on each
    file (its threads make each run differ: on one cleaned file its first fix came at 35, 53 and 59 s), every run's
    score in out["gnss_sdr_runs"] (with its losses of lock per PRN and the satellites it observed); its first run
    gives the ranges. gnss_sdr_dwells: its acquisition's (gnss_sdr_config's max_dwells)."""
    import shutil

    from ..defense import load_config
    from ..defense import clean_file
    from ..iq import format_by_name
    from ..receiver import NoSignal, run_file
    from .gnss_sdr import GNSS_SDR_EXE, LOG_NAME, lock_losses, run_gnss_sdr
    from .xgen import RECEIVER_SETTINGS, prepare, score
    data, reference = prepare(case, nav_path, work), prepare(case.clean, nav_path, work)
    cleaned = work / f"{case.tag}-clean.bin"
    summary = clean_file(data, cleaned, format_by_name(case.item_type), case.fs_hz, case.if_hz,
                         load_config(None, ['defense.mode="full"']))
    stopped = summary.internal_error or summary.input_error
    if stopped:   # a cleaned file cut short is no receiver's result (a full disk passed for GNSS-SDR's failure)
        raise RuntimeError(f"clean stopped at {summary.duration_s:.1f} s: {stopped}")
    week, sow = case.truth.start_gps
    t0_s = week * 604800.0 + sow + from_s
    out = {"case": case.tag, "cleaned": str(cleaned), "cancelled": list(summary.cancelled), "gave_up": summary.gave_up,
           "removed": list(summary.removed), "attenuation_db": summary.attenuation_db, "receivers": {}, "fixes": {}}
    plain = load_config(None, ['defense.mode="off"', *RECEIVER_SETTINGS])
    obs = {}
    for name, path in (("reference", reference), ("cleaned", cleaned)):
        run_dir = work / f"{case.tag}-plugin-{name}-semperfi"
        try:
            run_file(path, None, None, None, plain, run_dir, str(nav_path))
        except NoSignal:
            pass
        rinex = run_dir / "observations.rnx"
        obs[name] = read_ranges(rinex) if rinex.is_file() else {}
        fixes = score(run_dir / "fixes.csv", case.place, motion=case.motion) if (run_dir / "fixes.csv").is_file() \
            else {"fixes": 0}
        out["fixes"].setdefault("semperfi --defense off", {})[name] = fixes
    out["receivers"]["semperfi --defense off"] = range_differences(obs["reference"], obs["cleaned"], t0_s)
    if gnss_sdr and shutil.which(GNSS_SDR_EXE):
        for name, path in (("reference", reference), ("cleaned", cleaned)):
            runs = []
            for i in range(gnss_sdr_runs):
                run_dir = work / (f"{case.tag}-plugin-{name}-gnss-sdr" + (f"-{i}" if i else ""))
                shutil.rmtree(run_dir, ignore_errors=True)
                fixes = run_gnss_sdr(path, case.fs_hz, case.item_type, case.if_hz, run_dir, 1800.0, trop_model="OFF",
                                     rinex=True, max_dwells=gnss_sdr_dwells)
                found = sorted(p for p in run_dir.iterdir() if p.suffix[1:3].isdigit() and p.suffix[3:].upper() == "O")
                ranges = read_ranges(found[0]) if found else {}
                runs.append(_gnss_sdr_score(fixes, case) | {"lock_losses": lock_losses(run_dir / LOG_NAME),
                                                             "satellites": len(ranges)})
                if i == 0:
                    obs[name] = ranges
            out["fixes"].setdefault("gnss-sdr", {})[name] = runs[0]
            out.setdefault("gnss_sdr_runs", {})[name] = runs
        out["receivers"]["gnss-sdr"] = range_differences(obs["reference"], obs["cleaned"], t0_s)
    return out


def twin_summary(attenuation_db: dict) -> dict[str, dict]:
    """Per PRN, from `clean`'s attenuation report (CleanSummary.attenuation_db): its first stage's legitimate twin
    (offset from the spoofer in chips, the spoofer's advantage over it in dB, both as last measured) and the
    median of its measured attenuation windows (a lower bound counts as its value) -- what sets the residual a
    receiver behind the filter tracks the twin under."""
    out = {}
    for prn, stages in attenuation_db.items():
        first = stages[0] if stages else {}
        windows = [float(str(a).lstrip(">=")) for a in first.get("attenuation_db", [])]
        out[str(prn)] = {"offset_chips": first.get("legit_offset_chips"),
                         "advantage_db": first.get("twin_advantage_db"),
                         "attenuation_db": round(float(np.median(windows)), 1) if windows else None}
    return out


def _gnss_sdr_score(fixes, case, last_s: float = 10.0, rate_hz: float = 10.0) -> dict:
    """GNSS-SDR's fixes as xgen.score has ours: how many, the first (seconds into the recording: its GGA times are
    UTC, the case's GPS time), the horizontal error against the truth at each fix's time (the place, or the case's
    motion) over the last seconds and at most, and the share of its output epochs (rate_hz) from its first fix on
    that carry one (RTKLIB writes none for an epoch its chi-square test rejects); and, from its first fix to the
    recording's end, the share of those epochs with a true fix (within metrics.BAD_M) and the longest run without
    one (seconds): a fix late by a gap is as useless to a drone as none."""
    from .crosscheck import GPS_UTC_LEAP_S
    from .gnss_sdr import fixes_ecef
    from .metrics import BAD_M, availability, position_errors
    if not fixes:
        return {"fixes": 0}
    _, clock = case.date.split(",")
    h, m, sec = (float(v) for v in clock.split(":"))
    t_s = (np.array([f.t_sod_s for f in fixes]) + GPS_UTC_LEAP_S - (3600 * h + 60 * m + sec)) % 86400.0
    err = position_errors(t_s, fixes_ecef(fixes), case.truth).horizontal_m
    last = t_s >= t_s[-1] - last_s
    epochs = max(1, int(round((case.duration_s - t_s[0]) * rate_hz)))
    true_share, gap_s = availability(t_s, err <= BAD_M, float(t_s[0]), case.duration_s, rate_hz)
    return {"fixes": len(fixes), "first_fix_s": round(float(t_s[0]), 1),
            "last_mean_m": round(float(np.mean(err[last])), 2), "max_m": round(float(np.max(err)), 1),
            "epochs_fixed": round(min(1.0, len(fixes) / epochs), 3),
            "true_fixed": round(true_share, 3) if np.isfinite(true_share) else None,
            "longest_gap_s": round(gap_s, 1) if np.isfinite(gap_s) else None}


@dataclass(frozen=True)
class ResidualProfile:
    """What clean left of one PRN's spoofer, seen by a correlator slid across it (lags in chips from the spoofer's
    code phase): the residual's rms correlation, and its parts coherent with the spoofer's and with the twin's
    own per-millisecond correlation, in units of each one's amplitude. An amplitude or phase error of the
    subtraction is a triangle at lag 0; a delay error a step across it (-d left, +d right, d in chips); the twin's
    code sidelobe leaking into the spoofer's amplitude estimate a triangle at lag 0 coherent with the twin."""
    prn: int
    lags_chips: np.ndarray
    twin_offset_chips: float
    twin_to_spoofer: float        # the twin's amplitude over the spoofer's
    rms: np.ndarray               # |residual correlation| rms / spoofer amplitude
    spoofer_coherent: np.ndarray  # complex, / spoofer amplitude
    twin_coherent: np.ndarray     # complex, / twin amplitude


PROFILE_LAGS_CHIPS = np.arange(-2.0, 2.001, 0.05)
FRONT_END_SETTLE_S = 1e-3    # a front end's (xgen.FrontEnd) state settles within this: its response lasts microseconds


def residual_profile(case, nav_path: str | Path, work: Path, cleaned: Path, prn: int, at_s: float,
                     span_s: float = 2.0) -> ResidualProfile:
    """The residual of one PRN's spoofer over span_s seconds from at_s: the cleaned samples less the clean scene's
    mix (the same legitimate signals and noise, as xgen mixes them) hold only what clean left of the spoofer and
    what it took of anything else; each is correlated with the PRN's code around the spoofer's code phase (found on
    the spoofer's scene alone) and set against the spoofer's and the twin's own correlations. Behind a front end
    the scenes, rendered faster, go through the same front end as the mix did (complex recordings only)."""
    from ..gps import ca_code
    from ..gps import CA_CHIP_RATE_HZ, L1_HZ
    from ..receiver import DopplerGrid, acquire
    from .xgen import OUTPUT_SCALE, FrontEnd, prepare, recording_s, rendered, scenes
    if case.real or case.item_type != "ishort":
        raise ValueError("a residual profile reads int16 IQ recordings: not real samples at an IF, nor int8")
    legit_scene, spoof_scene = scenes(case, nav_path, work)
    if spoof_scene is None:
        raise ValueError("a residual profile needs a case with a static or moving spoofer")
    reference = prepare(case.clean, nav_path, work)
    fs = case.fs_hz
    n = int(round(span_s * fs))
    first = int(round(at_s * fs))
    if first < 0 or n <= 0 or at_s + span_s > recording_s(case):
        raise ValueError(f"a residual profile of {span_s:g} s from {at_s:g} s lies outside the "
                         f"{recording_s(case):g} s recording")
    up = int(round(rendered(case).fs_hz / fs))
    settle = min(first, int(round(FRONT_END_SETTLE_S * fs)))   # the front end's state, from this much earlier

    def iq16(path: Path, a: int, b: int) -> np.ndarray:
        iq = np.memmap(path, dtype=np.int16, mode="r")[2 * a:2 * b].astype(np.float64)
        return iq[0::2] + 1j * iq[1::2]

    def read_scene(path: Path, scale: float) -> np.ndarray:
        if up == 1:
            return scale * iq16(path, first, first + n)
        fast = iq16(path, (first - settle) * up, (first + n) * up)
        out = FrontEnd(case.front_end_hz, fs * up, up).filter(np.column_stack([fast.real, fast.imag]).ravel())
        return scale * (out[0::2] + 1j * out[1::2]).astype(np.complex128)[settle:]

    spoof = read_scene(spoof_scene, OUTPUT_SCALE * 10 ** (case.advantage_db / 20.0))
    legit = read_scene(legit_scene, OUTPUT_SCALE)

    def read(path: Path) -> np.ndarray:
        return iq16(path, first, first + n)

    residual = read(cleaned) - read(reference)
    look = int(round(0.02 * fs))
    grid = DopplerGrid(0.0, 5000.0, 50.0)
    ps = acquire(spoof[:look], fs, [prn], grid, coherent_ms=10, noncoherent=2)[prn].peaks[0]
    pl = acquire(legit[:look], fs, [prn], grid, coherent_ms=10, noncoherent=2)[prn].peaks[0]
    chips_per_sample = CA_CHIP_RATE_HZ * (1.0 + ps.doppler_hz / L1_HZ) / fs
    code = ca_code(prn).astype(np.float64)
    per_ms = int(round(fs * 1e-3))
    blocks = n // per_ms
    k = np.arange(blocks * per_ms)
    wipe = np.exp(-2j * np.pi * ps.doppler_hz * k / fs)

    def correlations(x: np.ndarray) -> np.ndarray:       # (lags, milliseconds)
        xw = x[:k.size] * wipe
        return np.array([(xw * code[np.floor(ps.code_phase_chips + lag + k * chips_per_sample).astype(np.int64) % 1023])
                         .reshape(blocks, per_ms).sum(axis=1) for lag in PROFILE_LAGS_CHIPS])

    cs, cl, cr = correlations(spoof), correlations(legit), correlations(residual)
    twin = float(((pl.code_phase_chips - ps.code_phase_chips + 511.5) % 1023) - 511.5)
    a_s = cs[int(np.argmin(np.abs(PROFILE_LAGS_CHIPS)))]
    a_t = cl[int(np.argmin(np.abs(PROFILE_LAGS_CHIPS - twin)))]
    return ResidualProfile(prn, PROFILE_LAGS_CHIPS, twin, float(np.mean(np.abs(a_t)) / np.mean(np.abs(a_s))),
                           np.sqrt(np.mean(np.abs(cr) ** 2, axis=1)) / np.mean(np.abs(a_s)),
                           np.mean(cr / a_s, axis=1), np.mean(cr / a_t, axis=1))

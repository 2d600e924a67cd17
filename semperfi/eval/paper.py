"""The paper's evaluation, figure by figure (issue 26): each function runs the scenarios behind one figure or table
of the paper, draws it, and returns our numbers beside the paper's.

Every recording is a cross-generator Case (semperfi.eval.xgen) rendered by our own simulator or GPS-SDR-SIM, so a
figure runs on either; the receiver is `semperfi run` in-process, measured by semperfi.eval.metrics against the
case's truth. Runs are cached by case and receiver settings (Runs): a figure that needs a run another has made
reuses it, and the integrity and availability figures read every run the suite made. A figure that fails is a
result (its error line), never the end of the suite.
"""

from __future__ import annotations

import math
import random
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..defense import MIN_SIGNATURE_M, PAPER_THRESHOLD_M
from ..flight import ManeuverLimits, draw
from ..iq import sidecar_path
from ..receiver import TRUSTED_STATES
from .metrics import Truth, fix_errors, position_errors, read_events, read_fixes, run_metrics
from .xgen import PLACES, Case, maneuver_case, recording_s, run_case, takeover_case

C_M_S = 299792458.0
PLACE = PLACES["boston"]         # the paper's live recordings were made in Boston (Northeastern University)
DATE = "2022/01/01,00:00:13"     # 13 s into a frame: the first fix needs the next subframe's TOW
MANEUVER_SEED = 26               # the suite's maneuvers are drawn seeded (reproducible figures); a UAV's are not


@dataclass(frozen=True)
class Plan:
    """What one suite runs: lengths, grids and repetitions."""
    name: str
    fs_hz: float = 2.6e6
    static_s: float = 40.0
    offsets_m: tuple[float, ...] = (500.0, 1000.0, 1500.0, 2000.0, 2500.0, 3000.0, 3500.0, 6200.0)
    static_db: float = 6.0
    powers_db: tuple[float, ...] = (3.0, 5.0, 10.0, 15.0)
    strong_offsets_m: tuple[float, ...] = (1000.0, 3000.0, 6200.0)
    maneuvers: int = 20
    flying_s: float = 80.0
    maneuver_at_s: float = 40.0
    takeover_s: float = 100.0
    takeover_hold_s: float = 15.0     # the paper's simulator trace: ~15 s in sync, then the push
    takeover_m_s: float = 8.0
    fly_m_s: float = 3.0              # the receiver's own flight north during the dynamic push
    push_s: float = 80.0
    push_at_s: float = 40.0
    timing_fs_hz: float = 10e6        # the paper's traces' rate
    timing_repeat: int = 3
    figures: tuple[str, ...] = ()     # empty: every figure


PLANS = {
    "paper": Plan("paper"),
    "full": Plan("full", offsets_m=tuple(float(m) for m in range(500, 6501, 500)) + (6200.0,), maneuvers=50,
                 powers_db=(3.0, 5.0, 10.0, 15.0, 20.0), strong_offsets_m=(500.0, 1000.0, 3000.0, 6200.0),
                 timing_repeat=5),
    "quick": Plan("quick", fs_hz=2.0e6, static_s=30.0, offsets_m=(1000.0, 3000.0), powers_db=(3.0, 15.0),
                  strong_offsets_m=(3000.0,), maneuvers=12, flying_s=50.0, maneuver_at_s=20.0, takeover_s=50.0,
                  push_s=40.0, push_at_s=18.0, timing_fs_hz=4e6, timing_repeat=1),
    # CI-sized: one short static attack and what needs no recording
    "tiny": Plan("tiny", fs_hz=2.0e6, static_s=20.0, offsets_m=(1000.0,), maneuvers=6, timing_fs_hz=2e6,
                 timing_repeat=1, figures=("static", "availability", "integrity", "maneuvers", "timing")),
}


@dataclass
class Figure:
    key: str
    title: str
    rows: list[tuple[str, str, str]] = field(default_factory=list)   # (what, the paper, ours)
    png: str | None = None
    note: str = ""
    error: str | None = None
    wall_s: float = 0.0


class Runs:
    """The receiver's runs of the suite, cached by case and settings, each with its metrics and outputs."""

    def __init__(self, nav_path: str | None, work: Path):
        self.nav_path, self.work = nav_path, work
        self.done: dict[tuple, dict] = {}
        self._first: dict[tuple, float | None] = {}

    def run(self, case: Case, defense: str = "full", ins: Path | None = None, sets: tuple[str, ...] = ()) -> dict:
        key = (case.tag, defense, str(ins), sets)
        if key not in self.done:
            clean_ttff = self._first_fix_s(case.clean, defense, ins, sets) if case.attacker else None
            r = run_case(case, self.nav_path, self.work, defense, imu_csv=ins, sets=sets)
            out = Path(r["out"])
            m = run_metrics(out / "fixes.csv", out / "events.jsonl", case.truth, recording_s(case), clean_ttff,
                            r["crash"], r["wall_s"])
            self.done[key] = {**r, **m, "label": f"{case.tag} {defense}" + (" imu" if ins else "") + "".join(sets),
                              "attacked": case.attacker, "truth": case.truth}
        return self.done[key]

    def _first_fix_s(self, case: Case, defense: str, ins, sets) -> float | None:
        """A clean scene's first fix (the availability span's start): from its whole run when one was made, else
        from a run that stops there."""
        whole = self.done.get((case.tag, defense, str(ins), sets))
        if whole is not None:
            return whole["first_fix_s"]
        key = ("first fix", case.tag, defense, str(ins), sets)
        if key not in self._first:
            r = run_case(case, self.nav_path, self.work, defense, imu_csv=ins, sets=sets, until_first_fix=True)
            self._first[key] = r.get("first_fix_s")
        return self._first[key]

    def forget_recordings(self) -> None:
        """Delete the recordings (the outputs stay): a suite's would fill a disk."""
        for path in self.work.glob("*.bin"):
            path.unlink(missing_ok=True)
            sidecar_path(path).unlink(missing_ok=True)
        shutil.rmtree(self.work / "scenes", ignore_errors=True)


@dataclass
class Context:
    plan: Plan
    generator: str
    runs: Runs
    out: Path                     # where the PNGs go

    def case(self, offset_m: float, advantage_db: float, duration_s: float, **kw) -> Case:
        return Case(PLACE, offset_m, advantage_db, date=DATE, duration_s=duration_s, fs_hz=self.plan.fs_hz,
                    generator=self.generator, **kw)

    def png(self, key: str) -> Path:
        return self.out / f"{key}-{self.generator}.png"


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _fmt(value, unit: str = "", digits: int = 1) -> str:
    return "-" if value is None or (isinstance(value, float) and not math.isfinite(value)) else \
        f"{value:.{digits}f}{unit}"


def _pct(share) -> str:
    return _fmt(None if share is None else 100 * share, " %")


def _span(values, unit: str, digits: int = 1) -> str:
    return f"{min(values):.{digits}f}-{max(values):.{digits}f}{unit}" if values else "-"


# -- the figures --------------------------------------------------------------------------------------------------

def maneuvers(ctx: Context) -> Figure:
    """The API's pseudorandom maneuvers against the paper's constraints (Fig. 'pseudorandom trajectories')."""
    fig = Figure("maneuvers", "Pseudorandom maneuvers of the Adversarial Peak Identifier")
    limits, rng = ManeuverLimits(), random.Random(MANEUVER_SEED)
    drawn = [draw(limits, rng=rng) for _ in range(ctx.plan.maneuvers)]
    plt = _pyplot()
    f, ax = plt.subplots(figsize=(6, 6))
    w = limits.corridor_half_width_m
    ax.axvspan(-w, w, color="red", alpha=0.15, label=f"no-maneuver zone ({2 * w:g} m wide, along the track)")
    for i, m in enumerate(drawn):
        ax.plot(m.east_m, m.north_m, lw=1.2)
        ax.annotate(str(i + 1), (m.east_m[-1], m.north_m[-1]), fontsize=7)
    ax.plot(0, 0, "k^", label="maneuver triggered (track heading north)")
    ax.set(xlabel="east (m)", ylabel="north (m)", aspect="equal",
           title=f"{len(drawn)} maneuvers (seed {MANEUVER_SEED}; a UAV draws from the OS's random source)")
    ax.legend(loc="lower left", fontsize=8)
    _save(ctx, fig, f)
    cross = [float(np.max(np.abs(m.east_m))) for m in drawn]
    fig.rows = [("flight time", "10-20 s", _span([m.duration_s for m in drawn], " s")),
                ("distance from the trigger at the end", ">= 30 m", _span([m.end_distance_m for m in drawn], " m")),
                ("path flown", "-", _span([m.path_length_m for m in drawn], " m")),
                ("leaves the no-maneuver zone", "20 m wide zone",
                 f"{sum(c > w for c in cross)}/{len(drawn)} (farthest from the track {_span(cross, ' m')})"),
                ("turns (not a straight line)", "required", f"{len(drawn)}/{len(drawn)} (checked by the draw)")]
    return fig


def _maneuver_tracks(run: dict, ins_csv: Path, at_s: float, length_s: float):
    """(t, GPS north/east, INS north/east) through the maneuver, each from its own value at the start (m)."""
    f = read_fixes(Path(run["out"]) / "fixes.csv")
    ins = np.loadtxt(ins_csv, delimiter=",", skiprows=1)
    t = f.get("t_rx_s", np.zeros(0))
    keep = (t >= at_s) & (t <= at_s + length_s)
    if keep.sum() < 2:
        return np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2))
    t = t[keep]
    enu = position_errors(t, np.column_stack([f["x_m"], f["y_m"], f["z_m"]])[keep],
                          Truth(PLACE.lat_deg, PLACE.lon_deg, PLACE.height_m)).enu
    gps = enu[:, [1, 0]] - enu[0, [1, 0]]
    ins_ne = np.column_stack([np.interp(t, ins[:, 0], ins[:, 1]), np.interp(t, ins[:, 0], ins[:, 2])])
    return t, gps, ins_ne - ins_ne[0]


def tracks(ctx: Context) -> Figure:
    """IMU against GPS through a maneuver, with and without an attacker (Fig. 'EKF vs GPS'); the defended run's
    verdict and recovery."""
    fig = Figure("tracks", "Inertial track against GPS through a maneuver, with and without an attacker")
    p = ctx.plan
    case, ins = maneuver_case(PLACE, 1000.0, p.static_db, ctx.runs.work, p.maneuver_at_s, p.flying_s, date=DATE,
                              fs_hz=p.fs_hz)
    case = replace(case, generator=ctx.generator)
    length_s = 20.0
    clean = _maneuver_tracks(ctx.runs.run(case.clean, "off"), ins, p.maneuver_at_s, length_s)
    spoofed = _maneuver_tracks(ctx.runs.run(case, "off"), ins, p.maneuver_at_s, length_s)
    defended = ctx.runs.run(case, "full", ins)
    dev = [np.hypot(*(g - i).T) for _, g, i in (clean, spoofed)]
    plt = _pyplot()
    f, (a, b) = plt.subplots(1, 2, figsize=(11, 4.5))
    a.plot(clean[2][:, 1], clean[2][:, 0], "k-", lw=2, label="INS (the vehicle's own estimate)")
    a.plot(clean[1][:, 1], clean[1][:, 0], "g--", label="GPS, no attacker")
    a.plot(spoofed[1][:, 1], spoofed[1][:, 0], "r-", label="GPS, spoofed (conventional receiver)")
    a.set(xlabel="east (m)", ylabel="north (m)", aspect="equal", title="the maneuver, from its start")
    a.legend(fontsize=8)
    b.plot(spoofed[0] - p.maneuver_at_s, np.maximum(dev[1], 0.05), "r", label="spoofed GPS vs INS")
    b.plot(clean[0] - p.maneuver_at_s, np.maximum(dev[0], 0.05), "g", label="legitimate GPS vs INS")
    b.axhline(PAPER_THRESHOLD_M, color="k", ls="--", lw=0.8, label=f"paper's threshold {PAPER_THRESHOLD_M:g} m")
    b.set(xlabel="time into the maneuver (s)", ylabel="|GPS - INS| displacement (m)", yscale="log")
    b.legend(fontsize=8)
    _save(ctx, fig, f)
    fig.rows = [("deviation without an attacker", "trivial", _fmt(np.max(dev[0]) if dev[0].size else None, " m max")),
                ("deviation under a static spoofer (1 km, +6 dB)", "significant",
                 _fmt(np.max(dev[1]) if dev[1].size else None, " m max")),
                ("decision threshold", f"{PAPER_THRESHOLD_M:g} m",
                 f"{MIN_SIGNATURE_M:g} m + the INS's drift bound (grows with time)"),
                ("defended: verdict / first recovered fix", "-",
                 f"{_fmt(defended['verdict_s'], ' s')} / {_fmt(defended['recovered_s'], ' s')}"),
                ("defended: last 10 s", "-", _fmt(defended["last_mean_m"], " m", 2))]
    return fig


AMPLITUDE_CASES = {1: "one satellite", 2: "one satellite, spoofed", 3: "8 satellites", 4: "8 satellites, each spoofed"}
AMPLITUDE_POWERS_DB = (0.0, 3.0, 6.0, 10.0, 15.0)
AMPLITUDE_FS_HZ = 4e6
AMPLITUDE_TRIALS = 4            # seeds per point


def _amplitude_errors(case: int, advantage_db: float, seed: int) -> list[float]:
    """|estimate / truth - 1| of the CAF-peak amplitude (the paper's equation 10, semperfi.defense.canceller) of
    every spoofer (cases 2, 4) or satellite (1, 3) in 60 ms of our simulator's signal; the spoofer 5 us off its
    twin (an unsynchronized one: the peaks stand apart, as the equation needs)."""
    from ..defense import caf_amplitude
    from ..sim import load_scenario
    from ..sim import Simulator
    spoofed = case in (2, 4)
    sets = [f"signal.fs_hz={AMPLITUDE_FS_HZ}", "time.duration_s=0.06", 'signal.format="gr_complex"',
            f"signal.seed={seed}", f"constellation.max_satellites={1 if case in (1, 2) else 8}",
            f"attacker.enabled={str(spoofed).lower()}", "attacker.time_offset_s=5e-6",
            f"attacker.power_advantage_db={advantage_db}"]
    sim, truth = Simulator(load_scenario(None, sets)), []
    x = np.concatenate(list(sim.chunks(lambda rx, sigs: truth.append(sigs))))
    errors = []
    for sig in truth[0]:
        if sig.source == ("spoof" if spoofed else "legit"):
            a_true = math.sqrt(10 ** (sig.cn0_dbhz / 10) * 2 * sim.noise_rms ** 2 / AMPLITUDE_FS_HZ)
            est = caf_amplitude(x, AMPLITUDE_FS_HZ, 0.0, sig.prn, sig.code_phase_chips, sig.doppler_hz)
            errors.append(abs(est / a_true - 1))
    return errors


def amplitude(ctx: Context) -> Figure:
    """Amplitude estimation accuracy in the paper's four cases against attacker power (Fig. 'amplitude
    estimation accuracy')."""
    fig = Figure("amplitude", "Amplitude estimation accuracy in four cases, against attacker power (our simulator)")
    plt = _pyplot()
    f, ax = plt.subplots(figsize=(7, 4))
    for case, name in AMPLITUDE_CASES.items():
        powers = AMPLITUDE_POWERS_DB if case in (2, 4) else (0.0,)
        acc = [100 * (1 - float(np.mean([e for seed in range(1, AMPLITUDE_TRIALS + 1)
                                          for e in _amplitude_errors(case, p, seed)]))) for p in powers]
        if case in (2, 4):
            ax.plot(powers, acc, "o-", label=f"case {case}: {name}")
        else:
            ax.axhline(acc[0], ls="--", color=f"C{case}", label=f"case {case}: {name} (no attacker)")
        fig.rows.append((f"case {case}: {name}", "accuracy grows with the attacker's power" if case in (2, 4)
                         else "-", ", ".join(f"{a:.1f} %" + (f" at +{p:g} dB" if case in (2, 4) else "")
                                             for p, a in zip(powers, acc))))
    ax.set(xlabel="attacker power advantage (dB)", ylabel="amplitude estimation accuracy (%)",
           title=f"eq. 10 at 45 dB-Hz, 20 ms, {AMPLITUDE_TRIALS} seeds per point")
    ax.legend(fontsize=8)
    _save(ctx, fig, f)
    return fig


def _peak_separation_ns(case: Case, nav_path: str | None) -> float | None:
    """The mean code-phase separation between each satellite's signal and its synchronized spoofer's at the start
    (their ranges from the true and from the claimed position), over the satellites above 10 degrees."""
    from ..gps import satellite_position
    from ..gps import azimuth_elevation, geodetic_to_ecef
    from ..sim import build_constellation
    from ..sim import load_scenario
    from .ours import scenario_sets
    from .xgen import claimed_place
    const = build_constellation(load_scenario(None, scenario_sets(case, nav_path)))
    true = geodetic_to_ecef(math.radians(PLACE.lat_deg), math.radians(PLACE.lon_deg), PLACE.height_m)
    c = claimed_place(case)
    claimed = geodetic_to_ecef(math.radians(c.lat_deg), math.radians(c.lon_deg), c.height_m)
    seps = []
    for eph in const.ephemerides.values():
        sat = np.asarray(satellite_position(eph, const.start.tow_s), float)
        if math.degrees(azimuth_elevation(true, sat)[1]) > 10.0:
            seps.append(abs(np.linalg.norm(claimed - sat) - np.linalg.norm(true - sat)) / C_M_S * 1e9)
    return float(np.mean(seps)) if seps else None


def static(ctx: Context) -> Figure:
    """Recovered against spoofed offset for static attacks, and the peak separation's effect on accuracy (Figs.
    'recovered offset and spoofed offset', 'effect of peak separation')."""
    fig = Figure("static", "Static spoofers: recovered against spoofed offset, and against peak separation")
    p = ctx.plan
    points = []
    for offset in p.offsets_m:
        case = ctx.case(offset, p.static_db, p.static_s)
        r = ctx.runs.run(case)
        points.append((offset, _peak_separation_ns(case, ctx.runs.nav_path), r["last_mean_m"], r["availability"]))
        ctx.runs.forget_recordings()
    plt = _pyplot()
    f, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    ok = [q for q in points if q[2] is not None]
    a.plot([q[0] / 1e3 for q in ok], [q[2] for q in ok], "o-")
    a.set(xlabel="spoofed offset (km)", ylabel="recovered offset, last 10 s (m)", yscale="log",
          title=f"+{p.static_db:g} dB, synchronized")
    b.plot([q[1] for q in ok if q[1]], [q[2] for q in ok if q[1]], "o-")
    b.set(xlabel="mean peak separation (ns)", ylabel="recovered offset (m)", yscale="log")
    _save(ctx, fig, f)
    paper = {6200.0: "2 m (simulator); live 4.1 km: 6 m"}
    fig.rows = [(f"spoofed {o / 1e3:g} km: recovered offset (separation)", paper.get(o, "-"),
                 f"{_fmt(e, ' m', 2)} ({_fmt(s, ' ns', 0)}, available {_pct(av)})")
                for o, s, e, av in points]
    seps = [s for _, s, _, _ in points if s]
    fig.rows.append(("peak separation over the offsets", "800 ns (500 m) - 5500 ns (3.5 km)", _span(seps, " ns", 0)))
    return fig


def _final_attenuations_db(report) -> list[float]:
    """Per PRN, the last attenuation its last SIC stage measured (the canceller's report in the defence summary:
    PRN -> [{stage, attenuation_db: [dB or '>=dB' (a lower bound)]}])."""
    out = []
    for stages in (report or {}).values():
        windows = stages[-1].get("attenuation_db") if isinstance(stages, list) and stages and \
            isinstance(stages[-1], dict) else None
        if windows:
            try:
                out.append(float(str(windows[-1]).lstrip(">=")))
            except ValueError:
                pass
    return out


def strong(ctx: Context) -> Figure:
    """A far stronger attacker: multi-stage attenuation as before/after acquisition plots, and spoofed against
    recovered offset at +15 dB (Figs. 'two step attenuation', 'spoofed vs recovered at 15 dB')."""
    from .demo import _before_after_plot
    from ..defense import load_config
    fig = Figure("strong", "A +15 dB attacker: multi-stage attenuation, and the recovered offset")
    p = ctx.plan
    for offset in p.strong_offsets_m:
        case = ctx.case(offset, 15.0, p.static_s)
        r = ctx.runs.run(case)
        events = read_events(Path(r["out"]) / "events.jsonl")
        stages = [e.get("stage", 0) for e in events if e.get("event") == "sic_iteration"]
        summary = next((e for e in events if e.get("event") == "defense_summary"), {})
        att = _final_attenuations_db(summary.get("attenuation_db"))
        fig.rows.append((f"spoofed {offset / 1e3:g} km at +15 dB: recovered offset, last 10 s", "-",
                         f"{_fmt(r['last_mean_m'], ' m', 2)} (last state {r['last_state']})"))
        fig.rows.append(("  SIC stages, attenuation per PRN", "2 steps",
                         f"{max(stages) + 1 if stages else 0} stage(s), {_span(att, ' dB')}"))
        if fig.png is None and r["alarm_s"] is not None:
            data = ctx.runs.work / f"{case.tag}.bin"
            cfg = load_config(None, ['defense.mode="full"'])
            if data.is_file():
                _before_after_plot(data, cfg, ctx.png(fig.key), min(recording_s(case) - 1.0, r["alarm_s"] + 8.0))
                fig.png = ctx.png(fig.key).name if ctx.png(fig.key).is_file() else None
        ctx.runs.forget_recordings()
    return fig


def scatter(ctx: Context) -> Figure:
    """The recovered navigation symbols in the I/Q plane per attacker power (Fig. 'discrete time scatter')."""
    from .scatter import plot_symbols, recovered_symbols
    fig = Figure("scatter", "Recovered navigation symbols per attacker power")
    results = []
    for power in ctx.plan.powers_db:
        s = recovered_symbols(ctx.case(1000.0, power, ctx.plan.static_s), ctx.runs.nav_path, ctx.runs.work)
        results.append(s)
        read = sum(n for n, _ in s.subframes.values())
        bad = sum(b for _, b in s.subframes.values())
        snr = list(s.bit_snr_db.values())
        fig.rows.append((f"+{power:g} dB: subframes failing parity / bit SNR",
                         "distorted at +15 dB" if power >= 15 else "clean",
                         f"{bad}/{read}, {_span(snr, ' dB')} over {len(snr)} PRNs"))
        ctx.runs.forget_recordings()
    plot_symbols(results, ctx.png(fig.key))
    fig.png = ctx.png(fig.key).name
    return fig


def dynamic_push(ctx: Context) -> Figure:
    """A dynamic position push on a flying receiver, recovered (Fig. 'recovered path, UTM')."""
    fig = Figure("dynamic_push", "A dynamic push on a flying receiver: recovered against legitimate path")
    p = ctx.plan
    case, ins = takeover_case(PLACE, p.takeover_hold_s, p.takeover_m_s, p.takeover_s, ctx.runs.work, date=DATE,
                              fs_hz=p.fs_hz, receiver_m_s=p.fly_m_s)
    case = replace(case, generator=ctx.generator)
    r = ctx.runs.run(case, "full", ins)
    off = ctx.runs.run(case, "off")
    plt = _pyplot()
    f, ax = plt.subplots(figsize=(7, 5))
    for run, defended in ((off, False), (r, True)):
        fx = read_fixes(Path(run["out"]) / "fixes.csv")
        if not fx or not fx["t_rx_s"].size:
            continue
        enu = fix_errors(fx, Truth(PLACE.lat_deg, PLACE.lon_deg, PLACE.height_m)).enu
        east, north = enu[:, 0], fx["t_rx_s"] * p.fly_m_s + enu[:, 1]
        if not defended:
            ax.plot(east, north, "r.", ms=2, label="conventional receiver")
            continue
        good = np.isin(fx["state"].astype(str), TRUSTED_STATES)
        ax.plot(east[good], north[good], "g.", ms=3, label="SemperFi, fixes called good")
        ax.plot(east[~good], north[~good], ".", color="orange", ms=2, label="SemperFi, not vouched for")
    t = np.linspace(0, recording_s(case), 50)
    ax.plot(np.zeros_like(t), t * p.fly_m_s, "k-", lw=1, label="legitimate path (north at "
                                                                f"{p.fly_m_s:g} m/s)")
    for when, what in ((0.0, "a: spoofer on, aligned"), (p.takeover_hold_s, "b: push starts"),
                       (r["verdict_s"], "c: verdict"), (r["recovered_s"], "d: recovered")):
        if when is not None:
            ax.annotate(what, (0.0, when * p.fly_m_s), xytext=(-40.0, when * p.fly_m_s), fontsize=8,
                        arrowprops={"arrowstyle": "-", "lw": 0.5})
    ax.set(xlabel="east of the legitimate path (m)", ylabel="north (m)",
           title=f"push {p.takeover_m_s:g} m/s east after {p.takeover_hold_s:g} s, +3 dB")
    ax.legend(fontsize=8)
    _save(ctx, fig, f)
    fig.rows = [("mean deviation of the recovered path, east", "10.1 m", _fmt(r.get("recovered_east_m"), " m", 2)),
                ("mean deviation of the recovered path, north", "2.6 m", _fmt(r.get("recovered_north_m"), " m", 2)),
                ("availability after the verdict (longest gap)", "-",
                 f"{_pct(r['availability_after_verdict'])} ({_fmt(r['longest_gap_after_verdict_s'], ' s')})"),
                ("conventional receiver, last 10 s", "follows the spoofer", _fmt(off["last_mean_m"], " m"))]
    ctx.runs.forget_recordings()
    return fig


def time_push(ctx: Context) -> Figure:
    """A time push: the time error of every fix against its TPL (not in the paper)."""
    fig = Figure("time_push", "A time push (25 ns/s): time error and its protection level")
    p = ctx.plan
    case = ctx.case(0.0, 10.0, p.push_s, push_ns_per_s=25.0, push_from_s=p.push_at_s)
    r = ctx.runs.run(case)
    off = ctx.runs.run(case, "off")
    from .metrics import time_errors_ns
    plt = _pyplot()
    f, ax = plt.subplots(figsize=(7, 4))
    for run, style, name in ((off, "r.", "conventional receiver"), (r, "g.", "SemperFi")):
        fx = read_fixes(Path(run["out"]) / "fixes.csv")
        terr = time_errors_ns(fx, case.truth.start_gps) if fx and fx["t_rx_s"].size else None
        if terr is not None:
            ax.plot(fx["t_rx_s"], terr, style, ms=2, label=name)
            if run is r and "tpl_ns" in fx:
                ax.fill_between(fx["t_rx_s"], -fx["tpl_ns"], fx["tpl_ns"], color="g", alpha=0.1, label="SemperFi's TPL")
    ax.axvline(p.push_at_s, color="k", ls="--", lw=0.8, label="push starts")
    ax.set(xlabel="time (s)", ylabel="time error (ns)", ylim=(-1500, 1500))
    ax.legend(fontsize=8)
    _save(ctx, fig, f)
    fig.rows = [("largest time error of a fix called good", "not shown", _fmt(r["time_err_max_ns"], " ns")),
                ("good fixes beyond their TPL", "not shown", str(r["good_beyond_tpl"])),
                ("time error over the last 10 s: SemperFi / conventional", "not shown",
                 f"{_fmt(r['time_err_last_ns'], ' ns')} / {_fmt(off['time_err_last_ns'], ' ns')}"),
                ("availability (longest gap)", "not shown",
                 f"{_pct(r['availability'])} ({_fmt(r['longest_gap_s'], ' s')})")]
    ctx.runs.forget_recordings()
    return fig


def timing(ctx: Context) -> Figure:
    """Time per cancellation iteration on this machine beside the paper's table, and verdict to recovered fix."""
    fig = Figure("timing", "Time per cancellation iteration, and from the verdict to the first recovered fix")
    n_prns, times = cancellation_iteration_s(ctx.runs.work, ctx.plan.timing_fs_hz, ctx.plan.timing_repeat)
    fig.rows = [(f"one iteration: {n_prns} spoofed PRNs, 1 s at {ctx.plan.timing_fs_hz / 1e6:g} MSa/s",
                 "Xeon 2.12 s, Core i7 2.79 s, Xavier 5.19 s, RPi 3B+ 11.57 s",
                 f"{min(times):.2f} s (best of {len(times)})")]
    runs = ctx.runs.done.values()
    after_verdict = [r["verdict_to_recovered_s"] for r in runs if r["verdict_s"] is not None and r["attacked"]
                     and r["verdict_to_recovered_s"] is not None]
    after_alarm = [r["verdict_to_recovered_s"] for r in runs if r["verdict_s"] is None and r["attacked"]
                   and r["verdict_to_recovered_s"] is not None]
    fig.rows += [("a maneuver's verdict to the first recovered fix", "~26 s (Xavier, 5 iterations)",
                  _span(after_verdict, " s") + f" over {len(after_verdict)} runs"),
                 ("no maneuver: the alarm to the first recovered fix (every range resolved)", "-",
                  _span(after_alarm, " s") + f" over {len(after_alarm)} runs")]
    return fig


def cancellation_iteration_s(work: Path, fs_hz: float, repeat: int) -> tuple[int, list[float]]:
    """One cancellation iteration as the paper's table times it: every spoofed PRN (8, +6 dB) through the canceller
    for 1 s of signal at fs_hz, then each re-acquired on the cleaned samples around its attacker's Doppler."""
    from ..defense import Canceller, refine_peak
    from ..iq import open_iq
    from ..receiver import DopplerGrid, acquire
    from ..sim import simulate_to_file
    from ..sim import load_scenario
    path = work / "iteration.bin"
    simulate_to_file(load_scenario(None, [f"signal.fs_hz={fs_hz}", "time.duration_s=2.5",
                                          "constellation.max_satellites=8", "attacker.enabled=true",
                                          "attacker.power_advantage_db=6.0", 'signal.format="gr_complex"']), path)
    x = open_iq(path).read(0, int(2.5 * fs_hz))
    head = x[: int(0.01 * fs_hz)]
    cafs = acquire(head, fs_hz, range(1, 33), DopplerGrid(0.0, 6000.0, 333.0), coherent_ms=2, noncoherent=5)
    peaks = [refine_peak(head, fs_hz, 0.0, c.best) for c in cafs.values() if c.best is not None and c.best.metric > 50]
    times = []
    for _ in range(repeat):
        canceller = Canceller(fs_hz)
        for peak in peaks:
            canceller.cancel(peak, 0)
        canceller.push(x[: int(1.0 * fs_hz)])                         # settle: pull-in and the first second
        t0 = time.perf_counter()
        cleaned = canceller.push(x[int(1.0 * fs_hz): int(2.0 * fs_hz)])
        for peak in peaks:
            acquire(cleaned[-int(0.01 * fs_hz):], fs_hz, [peak.prn], DopplerGrid(peak.doppler_hz, 2000.0, 333.0),
                    coherent_ms=2, noncoherent=5)
        times.append(time.perf_counter() - t0)
    path.unlink(missing_ok=True)
    sidecar_path(path).unlink(missing_ok=True)
    return len(peaks), times


def availability(ctx: Context) -> Figure:
    """Availability under attack and the longest gap, every attacked run of the suite (not in the paper)."""
    fig = Figure("availability", "Availability under attack (share of 10 Hz epochs with a fix within 10 m; and with "
                                 "one called good, what an autopilot is given)")
    attacked = [r for r in ctx.runs.done.values() if r["attacked"] and r["defense"] == "full"]
    for r in attacked:
        fig.rows.append((r["case"], "not shown",
                         f"{_pct(r['availability'])}, longest gap {_fmt(r['longest_gap_s'], ' s')}; called good: "
                         f"{_pct(r['good_availability'])}, longest gap {_fmt(r['longest_good_gap_s'], ' s')}"))
    if not attacked:
        fig.note = "no attacked run in this suite"
    return fig


def integrity(ctx: Context) -> Figure:
    """The Stanford diagram: horizontal error against HPL of every fix called good, over every run (not in the
    paper)."""
    fig = Figure("integrity", "Integrity: horizontal error against HPL of every fix called good (Stanford diagram)")
    errs, hpls, states = [], [], []
    for r in ctx.runs.done.values():
        if r["defense"] != "full":
            continue
        fx = read_fixes(Path(r["out"]) / "fixes.csv")
        if not fx or not fx["t_rx_s"].size or "hpl_m" not in fx:
            continue
        good = np.isin(fx["state"].astype(str), TRUSTED_STATES)
        errs.append(fix_errors(fx, r["truth"]).horizontal_m[good])
        hpls.append(fx["hpl_m"][good])
        states.append(fx["state"].astype(str)[good])
    err = np.concatenate(errs) if errs else np.zeros(0)
    hpl = np.concatenate(hpls) if hpls else np.zeros(0)
    plt = _pyplot()
    f, ax = plt.subplots(figsize=(6, 5))
    fin = np.isfinite(hpl) & (err > 0) & (hpl > 0)
    if fin.any():
        edges = np.logspace(-2, 3, 60)
        h = ax.hist2d(err[fin], hpl[fin], bins=[edges, edges], cmin=1, norm=_lognorm())
        f.colorbar(h[3], ax=ax, label="fixes")
    ax.plot([1e-2, 1e3], [1e-2, 1e3], "k-", lw=0.8)
    ax.axhline(40.0, color="r", ls=":", lw=0.8, label="alert limit 40 m (illustrative)")
    ax.set(xscale="log", yscale="log", xlabel="horizontal error (m)", ylabel="HPL (m)",
           title=f"{int(fin.sum())} good fixes, {len(errs)} runs")
    ax.legend(fontsize=8)
    _save(ctx, fig, f)
    beyond = int(np.sum(err[np.isfinite(hpl)] > hpl[np.isfinite(hpl)]))
    fig.rows = [("fixes called good (every defended run)", "not shown", str(err.size)),
                ("of them beyond their HPL (misleading information)", "not shown", str(beyond)),
                ("largest error / HPL ratio", "not shown",
                 _fmt(float(np.max(err[fin] / hpl[fin])) if fin.any() else None, "", 3))]
    return fig


def _save(ctx: Context, fig: Figure, f) -> None:
    """Lay out, write and close a matplotlib figure as the figure's PNG."""
    f.tight_layout()
    f.savefig(ctx.png(fig.key), dpi=110)
    _pyplot().close(f)
    fig.png = ctx.png(fig.key).name


def _lognorm():
    from matplotlib.colors import LogNorm
    return LogNorm()


FIGURES = {"maneuvers": maneuvers, "tracks": tracks, "amplitude": amplitude, "static": static, "strong": strong,
           "scatter": scatter, "dynamic_push": dynamic_push, "time_push": time_push, "timing": timing,
           "availability": availability, "integrity": integrity}     # the last three read every run before them
# figures whatever the generator: drawn once, after the others (timing reads every generator's runs)
ONCE = ("maneuvers", "amplitude", "timing")

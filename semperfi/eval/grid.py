"""Issue 22's evaluation grid ("uninterrupted under attack"): GPS-SDR-SIM scenes with its own path loss, started
across the navigation frame, under static spoofers of every distance and power, a flying receiver's maneuver under a
stronger and a weaker spoofer, a seamless takeover and a TEXBAT-like time push; each cell received by whatever
receiver is in the tree and measured by semperfi.eval.metrics against a clean run of the same scene (its first fix
starts the availability span).

A cell that crashes the receiver is a result (its error line), never the end of the grid.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, replace
from pathlib import Path

from .. import config
from ..iq import sidecar_path
from .metrics import run_metrics
from .xgen import (GENERATORS, GPS_SDR_SIM, OWN_DATE, PLACES, Case, maneuver_case, one_line, recording_s, run_case,
                   takeover_case)

# gps-sdr-sim without -p: each satellite at 20200 km / range times the antenna pattern, up to 11 dB under the fixed
# gain; the noise set so the fixed gain would stand at 49 dB-Hz puts the satellites at ~38-48 dB-Hz
PATH_LOSS_CN0_DBHZ = 49.0
# start times of day: midnight is a whole number of 30 s frames into the GPS week, so 00:00:00 starts subframe 1;
# 13 s and 21 s into that frame (subframes 3 and 4); 4 min 7 s later, elsewhere in the 12.5 min superframe (on
# 2022-01-01, TOW 518647: 7 s into the 14th of its 25 frames, subframe 2). gps-sdr-sim needs ephemerides valid then:
# the shared brdc0010.22n covers the whole day.
ISSUE22_TIMES = ("00:00:00", "00:00:13", "00:00:21", "00:04:07")
STATIC_OFFSETS_M = (500.0, 1000.0, 3000.0)
STATIC_POWERS_DB = (3.0, 6.0, 10.0, 20.0)
SHORT_EVENT_S = 12.0          # a shortened cell's maneuver, takeover or push starts here


@dataclass(frozen=True)
class Cell:
    """One attack on one scene. at_s: the flying receiver's maneuver start, the takeover's hold, the time push's
    start; rate: the takeover's push east (m/s) or the time push's (ns/s). Each field's domain is what a sweep's
    [space] may ask of it (config.check)."""
    kind: str                      # static | flying | takeover | push
    place: str = config.key("boston", choices=tuple(PLACES))
    date: str = OWN_DATE
    offset_m: float = config.key(1000.0, 0.0, 1.0e6, unit="m", doc="the claimed position's distance from the truth")
    advantage_db: float = config.key(6.0, -20.0, 40.0, unit="dB", doc="the attacker's power over the satellites'")
    duration_s: float = config.key(60.0, 5.0, 3600.0, unit="s")
    at_s: float = config.key(0.0, 0.0, 3600.0, unit="s")
    rate: float = config.key(0.0, -1.0e4, 1.0e4, doc="m/s (takeover) or ns/s (time push)")
    imu: bool = False
    fs_hz: float = config.key(2.6e6, 1.0e6, 25.0e6, unit="Hz")
    path_loss: bool = True
    cn0_dbhz: float = config.key(PATH_LOSS_CN0_DBHZ, 20.0, 60.0, unit="dB-Hz")
    azimuth_deg: float = config.key(90.0, -360.0, 360.0, unit="deg",
                                    doc="where the claimed position lies from the truth (static and flying cells)")
    noise_seed: int = 1            # the receiver noise's
    generator: str = config.key(GPS_SDR_SIM, choices=GENERATORS, doc="what renders the scene: gps-sdr-sim, or ours")

    @property
    def label(self) -> str:
        when = self.date.split(",")[1]
        what = {"static": f"static {self.offset_m:g} m",
                "flying": f"flying, maneuver at {self.at_s:g} s, spoofer {self.offset_m:g} m",
                "takeover": f"takeover, {self.rate:g} m/s E after {self.at_s:g} s",
                "push": f"time push {self.rate:g} ns/s from {self.at_s:g} s"}[self.kind]
        if self.azimuth_deg != 90.0 and self.kind in ("static", "flying"):
            what += f" at {self.azimuth_deg:g} deg"
        return (f"{self.place} {when} {what} {self.advantage_db:+g} dB{' imu' if self.imu else ''}"
                f"{'' if self.path_loss else ' no path loss'} {self.duration_s:g} s"
                f"{'' if self.generator == GPS_SDR_SIM else ' (' + self.generator + ')'}")

    def build(self, work: Path) -> tuple[Case, Path | None]:
        """The case (and the INS track for --imu, or None)."""
        place = PLACES[self.place]
        common = {"date": self.date, "fs_hz": self.fs_hz, "path_loss": self.path_loss, "cn0_dbhz": self.cn0_dbhz}
        if self.kind == "flying":
            case, ins = maneuver_case(place, self.offset_m, self.advantage_db, work, self.at_s, self.duration_s,
                                      **common)
        elif self.kind == "takeover":
            case, ins = takeover_case(place, self.at_s, self.rate, self.duration_s, work, self.advantage_db, **common)
        elif self.kind == "push":
            case, ins = Case(place, 0.0, self.advantage_db, duration_s=self.duration_s, push_ns_per_s=self.rate,
                             push_from_s=self.at_s, **common), None
        elif self.kind == "static":
            case, ins = Case(place, self.offset_m, self.advantage_db, duration_s=self.duration_s, **common), None
        else:
            raise ValueError(f"unknown cell kind {self.kind!r}")
        return (replace(case, azimuth_deg=self.azimuth_deg, seed=self.noise_seed, generator=self.generator),
                ins if self.imu else None)

    def shortened(self, duration_s: float) -> Cell:
        """The same attack in a shorter recording: a maneuver, takeover or push then starts at SHORT_EVENT_S."""
        return replace(self, duration_s=duration_s, at_s=SHORT_EVENT_S if self.kind != "static" else 0.0)


def issue22_cells(places=("boston",), fs_hz: float = 2.6e6, day: str = OWN_DATE.split(",")[0]) -> list[Cell]:
    """The grid: static spoofers 500 m / 1 km / 3 km east at +3/+6/+10/+20 dB from the first sample at every start
    time (60 s); the flying receiver's maneuver at 50 s under a spoofer 1 km east at +6 and -3 dB with its INS
    track (100 s); the seamless takeover, identical for 20 s at +3 dB then pushed east at 8 m/s (120 s); the time
    push, the legitimate scene itself at +10 dB delayed at 25 ns/s from 45 s (100 s). All with path loss, on day
    (YYYY/MM/DD: the navigation file's), the non-static cells from its midnight."""
    midnight = f"{day},00:00:00"
    cells = []
    for place in places:
        cells += [Cell("static", place, f"{day},{clock}", offset, power, 60.0, fs_hz=fs_hz)
                  for clock in ISSUE22_TIMES for offset in STATIC_OFFSETS_M for power in STATIC_POWERS_DB]
        cells += [Cell("flying", place, midnight, 1000.0, power, 100.0, at_s=50.0, imu=True, fs_hz=fs_hz)
                  for power in (6.0, -3.0)]
        cells.append(Cell("takeover", place, midnight, 0.0, 3.0, 120.0, at_s=20.0, rate=8.0, imu=True, fs_hz=fs_hz))
        cells.append(Cell("push", place, midnight, 0.0, 10.0, 100.0, at_s=45.0, rate=25.0, fs_hz=fs_hz))
    return cells


def pick(cells: list[Cell], n: int | None, seed: int) -> list[Cell]:
    """A seeded random subset of n cells (all of them for None), in the grid's order."""
    if n is None or n >= len(cells):
        return list(cells)
    chosen = set(random.Random(seed).sample(range(len(cells)), n))
    return [c for i, c in enumerate(cells) if i in chosen]


def run_cell(cell: Cell, nav_path: str | Path, work: Path, sets: tuple[str, ...] = (), clean: dict | None = None,
             clean_until_first_fix: bool = False, keep: bool = False) -> list[dict]:
    """The rows of one cell: its scene's clean run first when clean (a cache, scene -> row) does not hold it yet,
    then the attack, both measured by run_metrics. A failure of the harness itself (gps-sdr-sim, say) is the row's
    error too, crash None (not known)."""
    clean = {} if clean is None else clean
    rows = []
    try:
        case, ins = cell.build(work)
        key = (case.clean.scene, bool(ins), sets)
        if key not in clean:
            clean[key] = _measured(f"clean {cell.place} {cell.date.split(',')[1]} {Path(case.motion).stem or 'static'}"
                                   f" {cell.duration_s:g} s", case.clean, nav_path, work, ins, sets,
                                   None, clean_until_first_fix, keep)
            rows.append(clean[key])
        rows.append(_measured(cell.label, case, nav_path, work, ins, sets, clean[key].get("first_fix_s"), False,
                              keep))
    except Exception as exc:          # noqa: BLE001 -- one cell's failure is recorded, the grid goes on
        rows.append({"cell": cell.label, "crash": None, "error": "harness: " + one_line(exc)})
    return rows


def _measured(label: str, case: Case, nav_path, work: Path, ins, sets, clean_first_fix_s, until_first_fix: bool,
              keep: bool) -> dict:
    try:
        r = run_case(case, nav_path, work, imu_csv=ins, sets=sets, until_first_fix=until_first_fix)
    finally:
        if not keep:
            (work / f"{case.tag}.bin").unlink(missing_ok=True)
            sidecar_path(work / f"{case.tag}.bin").unlink(missing_ok=True)
    out = Path(r["out"])
    m = run_metrics(out / "fixes.csv", out / "events.jsonl", case.truth,
                    None if until_first_fix else recording_s(case), clean_first_fix_s, r["crash"], r["wall_s"])
    return {"cell": label, "case": case.tag, **m}


COLUMNS = (("crash", "crash"), ("clean 1st fix", "clean_first_fix_s"), ("1st fix", "first_fix_s"),
           ("avail", "availability"), ("longest gap", "longest_gap_s"),
           ("avail (good)", "good_availability"), ("gap (good)", "longest_good_gap_s"),
           ("avail after verdict", "availability_after_verdict"), ("gap after verdict", "longest_gap_after_verdict_s"),
           ("last 10 s", "last_mean_m"),
           ("max", "max_m"), ("good >10 m", "good_but_wrong"), ("good >HPL", "good_beyond_hpl"),
           ("good >VPL", "good_beyond_vpl"), ("good >TPL", "good_beyond_tpl"), ("good time err", "time_err_max_ns"),
           ("time err last 10 s", "time_err_last_ns"),
           ("alarm", "alarm_s"), ("verdict", "verdict_s"), ("recovered", "recovered_s"),
           ("to recovered", "verdict_to_recovered_s"), ("last state", "last_state"), ("wall", "wall_s"))
UNITS = {"clean_first_fix_s": " s", "first_fix_s": " s", "longest_gap_s": " s", "longest_good_gap_s": " s",
         "longest_gap_after_verdict_s": " s",
         "last_mean_m": " m", "max_m": " m",
         "time_err_max_ns": " ns", "time_err_last_ns": " ns", "alarm_s": " s", "verdict_s": " s",
         "recovered_s": " s", "verdict_to_recovered_s": " s", "wall_s": " s"}


def table_header() -> str:
    names = ["cell", *(name for name, _ in COLUMNS)]
    return "| " + " | ".join(names) + " |\n" + "|---" * len(names) + "|"


def table_row(row: dict) -> str:
    cells = [row["cell"]]
    for _, key in COLUMNS:
        value = row.get(key)
        if key == "crash":     # the error line of a crash (or of the harness), else no
            cells.append((row.get("error") or "yes").replace("|", "/") if value or row.get("error") else "no")
        elif key in ("availability", "good_availability", "availability_after_verdict") and value is not None:
            cells.append(f"{100 * value:.1f} %")
        else:
            cells.append("-" if value is None else f"{value}{UNITS.get(key, '')}")
    return "| " + " | ".join(cells) + " |"

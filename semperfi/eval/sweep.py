"""Scenario sweeps (issue 26): a grid, or a seeded random sample, over the scenario space of issue 22's grid (place,
start time within the navigation frame, attack kind, offset and azimuth, attacker power, C/N0, rate, length, flying
receiver with its INS track), each cell a GPS-SDR-SIM scene received by SemperFi and measured like that grid
(grid.run_cell: crash, availability and longest gap, accuracy over the last 10 s, verdict-to-recovered latency, fixes
called good beyond their protection levels, wall time).

Cells run as Ray tasks when Ray is installed (`ray.init()` on this machine, or a cluster's address), else in a local
process pool. Each finished cell is one row appended to DIR/results.csv at once (and the table rewritten as
DIR/results.parquet when pyarrow is there), keyed by a hash of the cell's parameters: a rerun skips the cells
already there, so a sweep killed halfway loses only the cells it was running. A cell whose worker dies is a row
too, with its error and the command that reproduces it.

The spec (TOML):

    [sweep]
    sample = "grid"          # every combination of [space]; or "random": `cells` draws seeded by `seed`
    cells = 100
    seed = 1
    sets = []                # the receiver's --set overrides

    [space]                  # each key a list of values, or for a random sample also {min = .., max = ..}
    kind = ["static"]        # static | flying | takeover | push
    place = ["boston", "sydney"]
    start_s = [0, 13, 21]    # the recording's start, seconds after the navigation file's midnight
    offset_m = [500, 1000, 3000]
    advantage_db = [3, 6, 10]
"""

from __future__ import annotations

import csv
import fcntl
import hashlib
import json
import os
import random
import shutil
import tomllib
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import asdict, dataclass, fields
from itertools import product
from pathlib import Path
from typing import Callable, Iterator

from .. import config
from ..errors import BadInput
from .grid import COLUMNS, Cell, run_cell
from .pool import worker_pool
from .xgen import GPS_SDR_SIM, ephemeris_day, gps_sdr_sim_path, one_line

RESULTS_CSV = "results.csv"
LOCK = ".sweep.lock"
CELL_FIELDS = tuple(f.name for f in fields(Cell))
SPACE_KEYS = ("start_s", *(name for name in CELL_FIELDS if name != "date"))
KINDS = ("static", "flying", "takeover", "push")
METRIC_KEYS = tuple(key for _, key in COLUMNS) + ("error",)
ROW_KEYS = ("cell_id", *CELL_FIELDS, *METRIC_KEYS, "repro")
MAX_START_S = 86400.0 - 1.0   # the navigation file's day (gps-sdr-sim wants ephemerides valid at the start)


class SweepError(BadInput):
    """A spec or a results table that cannot be used (one line for the user)."""


@dataclass(frozen=True)
class SweepHead:
    """A spec's [sweep] table."""
    sample: str = config.key("grid", choices=("grid", "random"),
                             doc="every combination of the [space] values, or a seeded random sample of them")
    cells: int = config.key(100, 1, 1_000_000, doc="how many cells a random sample draws")
    seed: int = config.key(1, doc="the random sample's seed")
    sets: list = config.key([], doc="receiver settings for every cell, KEY=VALUE as `semperfi run --set` takes them")


@dataclass(frozen=True)
class Spec:
    path: Path
    sample: str
    n_cells: int
    seed: int
    sets: tuple[str, ...]
    space: dict


def load_spec(path: str | Path) -> Spec:
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SweepError(f"{path}: cannot read the sweep spec ({one_line(exc)})") from None
    space = doc.pop("space", {})
    if not isinstance(space, dict):
        raise SweepError(f"{path}: [space] must be a table")
    unknown = sorted(set(space) - set(SPACE_KEYS))
    if unknown:
        raise SweepError(f"{path}: unknown key {unknown[0]!r} (space keys: {', '.join(SPACE_KEYS)})")
    sections = {"sweep": SweepHead}
    try:
        head = config.merge(config.defaults(sections), doc)
        config.check(head, sections)
    except ValueError as exc:
        raise SweepError(f"{path}: {exc}") from None
    head = config.section(head, "sweep", SweepHead)
    if not all(isinstance(s, str) for s in head.sets):
        raise SweepError(f"{path}: sweep.sets must be a list of strings (KEY=VALUE)")
    sample = head.sample
    for key, values in space.items():
        ranged = isinstance(values, dict)
        if ranged and (sample == "grid" or set(values) - {"min", "max"} or not all(
                isinstance(values.get(k), (int, float)) and not isinstance(values.get(k), bool)
                for k in ("min", "max")) or values["min"] > values["max"]):
            raise SweepError(f"{path}: {key}: a range is {{min = .., max = ..}}, min <= max, in a random sample only")
        if not ranged and not (isinstance(values, list) and values):
            raise SweepError(f"{path}: {key} must be a non-empty list of values")
    spec = Spec(path, sample, head.cells, head.seed, head.sets, space)
    for cell in cells_of(spec, "2022/01/01,00:00:00"):     # every value checked before anything runs
        _check(cell, path)
    return spec


def _check(cell: Cell, path: Path) -> None:
    """A cell's values against their domains (the Cell's fields), one line naming the first one outside."""
    if cell.kind not in KINDS:
        raise SweepError(f"{path}: kind {cell.kind!r} is not one of {', '.join(KINDS)}")
    try:
        config.check({"space": asdict(cell)}, {"space": Cell})
    except ValueError as exc:
        raise SweepError(f"{path}: {exc}") from None
    if not isinstance(cell.imu, bool) or not isinstance(cell.path_loss, bool):
        raise SweepError(f"{path}: imu and path_loss are true or false")
    if not isinstance(cell.noise_seed, int) or isinstance(cell.noise_seed, bool):
        raise SweepError(f"{path}: noise_seed must be a whole number")


def _cell(values: dict, day: str) -> Cell:
    values = {"kind": "static", **values}
    start_s = values.pop("start_s", 0.0)
    if isinstance(start_s, bool) or not isinstance(start_s, (int, float)) or not 0.0 <= start_s <= MAX_START_S:
        raise SweepError(f"start_s = {start_s!r} is outside the navigation file's day [0, {MAX_START_S:g}]")
    s = int(round(start_s))
    return Cell(date=f"{day.split(',')[0]},{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}", **values)


def cells_of(spec: Spec, day: str) -> list[Cell]:
    """The spec's cells on the navigation file's day (YYYY/MM/DD,...), in a fixed order."""
    keys = sorted(spec.space)
    if spec.sample == "grid":
        return [_cell(dict(zip(keys, combo)), day) for combo in product(*(spec.space[k] for k in keys))]
    rng = random.Random(spec.seed)
    cells = []
    for _ in range(spec.n_cells):
        values = {}
        for k in keys:
            v = spec.space[k]
            values[k] = round(rng.uniform(v["min"], v["max"]), 3) if isinstance(v, dict) else rng.choice(v)
        cells.append(_cell(values, day))
    return cells


def cell_id(cell: Cell, sets: tuple[str, ...] = ()) -> str:
    """What names a cell in the results: a hash of its parameters and the receiver's overrides."""
    params = asdict(cell)
    if params["generator"] == GPS_SDR_SIM:      # the ids of the tables written before there was a choice
        del params["generator"]
    text = json.dumps({"cell": params, "sets": list(sets)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def run_one(cell: Cell, nav_path: str, work: Path, sets: tuple[str, ...]) -> dict:
    """One cell, measured: its clean scene run to its first fix (the availability span's start), then the attack.
    The scenes are deleted afterwards; the receiver's outputs stay in work."""
    try:
        rows = run_cell(cell, nav_path, work, sets, clean_until_first_fix=True)
    finally:
        shutil.rmtree(work / "scenes", ignore_errors=True)
    attack = rows[-1]
    return {key: attack.get(key) for key in METRIC_KEYS}


def _task(cell_dict: dict, nav_path: str, work: str, sets: tuple[str, ...]) -> dict:
    return run_one(Cell(**cell_dict), nav_path, Path(work), sets)


class Results:
    """DIR/results.csv, one row per finished cell, appended as cells finish (a torn last line from a kill is cut).
    One writer at a time: a second sweep on the same DIR is refused while the first holds DIR/.sweep.lock (the
    operating system lets it go when its holder dies, however it dies)."""

    def __init__(self, out_dir: Path):
        out_dir.mkdir(parents=True, exist_ok=True)
        self._lock = open(out_dir / LOCK, "w")
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._lock.close()
            raise SweepError(f"{out_dir}: another sweep is writing these results") from None
        self.csv = out_dir / RESULTS_CSV
        self.done: set[str] = set()      # the finished cells' ids
        if self.csv.exists():
            self.done = {r["cell_id"] for r in read_results(self.csv)}
            self._cut_torn_tail()
        else:
            with open(self.csv, "w", newline="") as f:
                csv.writer(f).writerow(ROW_KEYS)

    def _cut_torn_tail(self) -> None:
        data = self.csv.read_bytes()
        if data and not data.endswith(b"\n"):
            with open(self.csv, "r+b") as f:
                f.truncate(data.rfind(b"\n") + 1)

    def add(self, row: dict) -> None:
        with open(self.csv, "a", newline="") as f:
            csv.writer(f).writerow(["" if row.get(k) is None else row[k] for k in ROW_KEYS])
            f.flush()
            os.fsync(f.fileno())
        self.done.add(row["cell_id"])
        write_parquet(self.csv)

    def close(self) -> None:
        self._lock.close()


def read_results(path: str | Path) -> list[dict]:
    """The rows of a results table (CSV or Parquet) that are whole and carry a cell id, the first of each id."""
    path = Path(path)
    try:
        if path.suffix == ".parquet":
            import pyarrow.parquet as pq
            rows = pq.read_table(path).to_pylist()
        else:
            with open(path, newline="") as f:
                reader = csv.DictReader(f)
                if reader.fieldnames is None or "cell_id" not in reader.fieldnames:
                    raise SweepError(f"{path}: not a sweep results table (no cell_id column)")
                rows = [r for r in reader if None not in r and None not in r.values()]
    except ImportError:
        raise SweepError(f"{path}: reading Parquet needs pyarrow (pip install semperfi[sweep])") from None
    except (OSError, UnicodeDecodeError, csv.Error, ValueError) as exc:
        raise SweepError(f"{path}: cannot read the results ({one_line(exc)})") from None
    seen, out = set(), []
    for r in rows:
        if r.get("cell_id") and r["cell_id"] not in seen:
            seen.add(r["cell_id"])
            out.append({k: (None if r.get(k) == "" else r.get(k)) for k in ROW_KEYS})
    return out


def write_parquet(csv_path: Path) -> bool:
    """The CSV table again as Parquet beside it (False when pyarrow is not installed)."""
    try:
        import pyarrow.csv as pacsv
        import pyarrow.parquet as pq
    except ImportError:
        return False
    table = pacsv.read_csv(csv_path)
    tmp = csv_path.with_suffix(".parquet.tmp")
    pq.write_table(table, tmp)
    tmp.replace(csv_path.with_suffix(".parquet"))
    return True


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def _pool_runner(jobs: list[tuple[Cell, str]], nav_path: str, out_dir: Path, sets, workers: int
                 ) -> Iterator[tuple[Cell, str, dict | BaseException]]:
    with worker_pool(workers) as pool:
        pending = {pool.submit(_task, asdict(c), nav_path, str(out_dir / "cells" / i), sets): (c, i) for c, i in jobs}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                c, i = pending.pop(fut)
                try:
                    yield c, i, fut.result()
                except Exception as exc:          # noqa: BLE001 -- a dead worker is the cell's result
                    yield c, i, exc


def _ray_runner(jobs: list[tuple[Cell, str]], nav_path: str, out_dir: Path, sets, address: str | None
                ) -> Iterator[tuple[Cell, str, dict | BaseException]]:
    import ray
    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    remote = ray.remote(num_cpus=1, max_retries=0)(_task)
    refs = {remote.remote(asdict(c), nav_path, str(out_dir / "cells" / i), sets): (c, i) for c, i in jobs}
    while refs:
        ready, _ = ray.wait(list(refs), num_returns=1)
        c, i = refs.pop(ready[0])
        try:
            yield c, i, ray.get(ready[0])
        except Exception as exc:                  # noqa: BLE001 -- a dead worker is the cell's result
            yield c, i, exc


@dataclass
class SweepSummary:
    cells: int
    skipped: int
    ran: int
    failed: int
    backend: str


def run_sweep(spec: Spec, nav_path: str | Path, out_dir: str | Path, backend: str = "auto", workers: int = 2,
              ray_address: str | None = None, on_row: Callable[[dict, int, int], None] | None = None,
              limit: int | None = None) -> SweepSummary:
    """Run every cell of spec not yet in out_dir's results; backend: "ray", "pool" or "auto" (Ray when installed).
    on_row(row, done, total) is told of each finished cell; limit: stop after this many (a test's kill)."""
    if gps_sdr_sim_path() is None:
        raise SweepError("gps-sdr-sim is not on PATH (the sweep's cells are GPS-SDR-SIM scenes)")
    if backend == "auto":
        backend = "ray" if ray_available() else "pool"
    if backend == "ray" and not ray_available():
        raise SweepError("Ray is not installed (pip install semperfi[sweep]); --pool runs the cells here")
    out_dir = Path(out_dir)
    cells = cells_of(spec, ephemeris_day(nav_path))
    results = Results(out_dir)
    done = results.done
    jobs, seen = [], set()
    for c in cells:
        i = cell_id(c, spec.sets)
        if i not in done and i not in seen:
            seen.add(i)
            jobs.append((c, i))
    skipped = len(cells) - len(jobs)
    jobs = jobs[:limit] if limit is not None else jobs
    runner = (_ray_runner(jobs, str(nav_path), out_dir, spec.sets, ray_address) if backend == "ray"
              else _pool_runner(jobs, str(nav_path), out_dir, spec.sets, workers))
    ran = failed = 0
    try:
        for c, i, outcome in runner:
            if isinstance(outcome, BaseException):
                outcome = {"crash": None, "error": "worker: " + one_line(outcome)}
            row = {"cell_id": i, **asdict(c), **outcome,
                   "repro": f"semperfi eval --sweep {spec.path} --nav {nav_path} --out {out_dir} --only {i}"}
            results.add(row)
            ran += 1
            failed += bool(row.get("crash") or row.get("error"))
            if on_row is not None:
                on_row(row, skipped + ran, len(cells))
    finally:
        results.close()
    return SweepSummary(len(cells), skipped, ran, failed, backend)


def run_only(spec: Spec, nav_path: str | Path, out_dir: str | Path, wanted: str) -> dict:
    """One cell of the spec, by its id, run here (what a row's repro command does); the results table is left as
    it is."""
    for c in cells_of(spec, ephemeris_day(nav_path)):
        if cell_id(c, spec.sets) == wanted:
            return {"cell_id": wanted, **asdict(c),
                    **run_one(c, str(nav_path), Path(out_dir) / "repro" / wanted, spec.sets)}
    raise SweepError(f"{spec.path}: no cell {wanted!r} in this sweep")

"""`semperfi eval --suite paper|quick|full`: the paper's evaluation by one command (issue 26).

Each figure of semperfi.eval.paper runs on each generator asked for (ours always; GPS-SDR-SIM when it is found),
and the suite writes, as each figure finishes, DIR/figures.json (every figure: our numbers beside the paper's) and
DIR/runs.csv (every receiver run's metrics), then DIR/report.html with the PNGs beside it. `semperfi report
DIR/figures.json` renders the report again without running anything.
"""

from __future__ import annotations

import csv
import html
import json
import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable

from ..errors import BadInput
from .grid import COLUMNS
from .paper import FIGURES, ONCE, PLANS, Context, Figure, Runs
from .sweep_report import page_head
from .xgen import GPS_SDR_SIM, OURS, gps_sdr_sim_path, one_line

FIGURES_JSON = "figures.json"
RUNS_CSV = "runs.csv"
ANY = "any generator"            # the figures that need no recording: drawn once
RUN_KEYS = ("generator", "label", *(key for _, key in COLUMNS), "error")


class SuiteError(BadInput):
    """A suite that cannot run as asked (one line for the user)."""


def generators(wanted: str) -> tuple[str, ...]:
    """ours, gps-sdr-sim or both ('auto': ours, and GPS-SDR-SIM when it is found)."""
    found = gps_sdr_sim_path() is not None
    if wanted == "auto":
        return (OURS, GPS_SDR_SIM) if found else (OURS,)
    chosen = (OURS, GPS_SDR_SIM) if wanted == "both" else (wanted,)
    if GPS_SDR_SIM in chosen and not found:
        raise SuiteError("gps-sdr-sim is not on PATH (build it from github.com/osqzss/gps-sdr-sim: one gcc line)")
    return chosen


def run_suite(name: str, out_dir: str | Path, nav_path: str | None, wanted: str = "auto",
              told: Callable[[str, Figure], None] | None = None) -> Path:
    """Run a suite's figures on each generator; the report's path."""
    if name not in PLANS:
        raise SuiteError(f"no suite {name!r} (one of {', '.join(PLANS)})")
    plan = PLANS[name]
    chosen = generators(wanted)
    if GPS_SDR_SIM in chosen and nav_path is None:
        raise SuiteError("GPS-SDR-SIM renders from a RINEX navigation file: give --nav (or --generator ours)")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    done: list[dict] = []
    runs_rows: list[dict] = []
    wanted = [k for k in plan.figures or FIGURES]
    every = Runs(nav_path, out / "work")           # every generator's runs, for the figures drawn once
    for generator in (*chosen, ANY):
        runs = every if generator == ANY else Runs(nav_path, out / "work" / generator)
        runs.work.mkdir(parents=True, exist_ok=True)
        ctx = Context(plan, chosen[0] if generator == ANY else generator, runs, out)
        for key in (k for k in wanted if (k in ONCE) == (generator == ANY)):
            t0 = time.perf_counter()
            try:
                fig = FIGURES[key](ctx)
            except Exception as exc:      # noqa: BLE001 -- one figure's failure is its result, the suite goes on
                fig = Figure(key, FIGURES[key].__doc__.split("\n")[0], error=one_line(exc))
            finally:
                runs.forget_recordings()
            fig.wall_s = round(time.perf_counter() - t0, 1)
            done.append({"generator": generator, **asdict(fig)})
            (out / FIGURES_JSON).write_text(json.dumps({"suite": name, "figures": done}, indent=1))
            if told:
                told(generator, fig)
        if generator != ANY:
            every.done |= {(generator, *key): r for key, r in runs.done.items()}
            runs_rows += [{"generator": generator, **r} for r in runs.done.values()]
            _write_runs(out / RUNS_CSV, runs_rows)
    return render_suite_report(out / FIGURES_JSON)


def _write_runs(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, RUN_KEYS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)


def read_figures(path: str | Path) -> tuple[str, list[dict]]:
    """A suite's figures.json: (suite name, figures); SuiteError when it is not one."""
    try:
        doc = json.loads(Path(path).read_text())
        figures = doc["figures"]
        if not isinstance(figures, list) or not all(isinstance(f, dict) and "key" in f for f in figures):
            raise ValueError("figures malformed")
        return str(doc["suite"]), figures
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise SuiteError(f"{path}: not a suite's {FIGURES_JSON} ({one_line(exc)})") from None


def _cell(value) -> str:
    return f"<td>{html.escape('' if value is None else str(value))}</td>"


def render_suite_report(figures_json: str | Path) -> Path:
    """DIR/report.html from DIR/figures.json (and DIR/runs.csv when there): each figure with its PNG and its
    table, our numbers beside the paper's."""
    name, figures = read_figures(figures_json)
    out = Path(figures_json).parent
    parts = [*page_head(f"SemperFi against the paper: the {name} suite"),
             "<p>Each figure of <i>SemperFi: A Spoofer Eliminating GPS Receiver for UAVs</i> (NDSS'22) run again, "
             "with the paper's number beside ours; the last figures are what the paper did not show. "
             f"Generators: {html.escape(', '.join(sorted({f['generator'] for f in figures})))}.</p>"]
    for f in figures:
        parts.append(f"<h2>{html.escape(str(f.get('title')))} <small>({html.escape(str(f.get('generator')))}, "
                     f"{f.get('wall_s')} s)</small></h2>")
        if f.get("error"):
            parts.append(f"<p style='color:#b00'>failed: {html.escape(str(f['error']))}</p>")
        if f.get("png"):
            parts.append(f"<img src='{html.escape(str(f['png']))}' alt='{html.escape(str(f.get('title')))}'>")
        if f.get("rows"):
            parts.append("<table><tr><th>what</th><th>paper</th><th>SemperFi (this run)</th></tr>")
            parts += ["<tr>" + "".join(_cell(v) for v in row) + "</tr>" for row in f["rows"]]
            parts.append("</table>")
        if f.get("note"):
            parts.append(f"<p>{html.escape(str(f['note']))}</p>")
    runs_csv = out / RUNS_CSV
    if runs_csv.is_file():
        with open(runs_csv, newline="") as fh:
            rows = list(csv.DictReader(fh))
        parts.append("<h2>Every receiver run</h2><table><tr>" + "".join(f"<th>{html.escape(k)}</th>" for k in RUN_KEYS)
                     + "</tr>")
        parts += ["<tr>" + "".join(_cell(r.get(k)) for k in RUN_KEYS) + "</tr>" for r in rows]
        parts.append("</table>")
    parts.append("</body></html>")
    report = out / "report.html"
    report.write_text("\n".join(parts))
    return report

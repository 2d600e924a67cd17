"""Cross-check an IQ file with GNSS-SDR: how many fixes, when the first, and how far from where they should be.

    python -m semperfi.eval.crosscheck OUT.bin [--truth OUT.truth-receiver.csv]
                                       [--reference-lat DEG --reference-lon DEG | --claimed] [--track]
                                       [--fs HZ] [--format ishort|ibyte|gr_complex] [--if HZ] [--out-dir DIR]

Sample rate, format and IF come from OUT.sigmf-meta unless given. The reference point is, in order of precedence,
--reference-lat/--reference-lon, the first claimed (attacker) position in the truth file with --claimed, or the
truth file's first row; --track compares each fix with the truth position at the fix's own time instead.
Exit status: 0 with at least one fix, 1 when GNSS-SDR produced none, 2 on a usage or run error.
"""

from __future__ import annotations

import csv
import math
import sys
import time
from pathlib import Path

import click
import numpy as np
import pymap3d

from ..errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, BadInput
from ..iq import format_by_name, format_by_sigmf_datatype
from .gnss_sdr import (COMPLEX_ITEM_TYPES, IONO_MODELS, TROP_MODELS, LOG_NAME, Fix, error_summary_m, fixes_ecef,
                       gnss_sdr_version, horizontal_errors_m, run_gnss_sdr)
from .metrics import errors

GPS_UTC_LEAP_S = 18   # GPS - UTC since 2017-01-01; GNSS-SDR's RTKLIB turns GPS time into UTC with its own table


class CrosscheckError(BadInput):
    """A problem worth one line to the user."""


def _sidecar_params(iq_path: Path) -> dict:
    """fs_hz / item_type / if_hz from the file's SigMF sidecar, as far as it says (empty when there is none)."""
    from ..iq import find_sidecar, read_sigmf_meta
    meta_path = find_sidecar(iq_path)
    if meta_path is None:
        return {}
    meta = read_sigmf_meta(meta_path)   # ValueError: one line naming the file
    params = {"sidecar": meta_path}
    if meta.sample_rate_hz is not None:
        params["fs_hz"] = meta.sample_rate_hz
    try:
        params["item_type"] = format_by_sigmf_datatype(meta.datatype).name
    except ValueError as exc:
        raise CrosscheckError(f"{meta_path}: {exc}") from None
    if_hz = meta.implied_if_hz()
    if if_hz is not None:
        params["if_hz"] = if_hz
    return params


def _float_or_none(text: str | None) -> float | None:
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def read_truth(truth_path: Path) -> dict[str, np.ndarray]:
    """The receiver truth columns we use, as float arrays (nan where a cell is empty)."""
    cols = ("t_rx_s", "gps_tow_s", "lat_deg", "lon_deg", "height_m", "claimed_lat_deg", "claimed_lon_deg")
    data: dict[str, list] = {c: [] for c in cols}
    try:
        with open(truth_path, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            missing = [c for c in cols[:5] if c not in (reader.fieldnames or [])]
            if missing:
                raise CrosscheckError(f"{truth_path}: not a receiver truth file (no column {', '.join(missing)})")
            for row in reader:
                for c in cols:
                    v = _float_or_none(row.get(c))
                    data[c].append(math.nan if v is None else v)
    except OSError as exc:
        raise CrosscheckError(f"cannot read truth file {truth_path}: {exc.strerror or exc}") from None
    out = {c: np.asarray(v, dtype=float) for c, v in data.items()}
    if out["t_rx_s"].size == 0 or not np.isfinite(out["lat_deg"][0]):
        raise CrosscheckError(f"{truth_path}: no truth rows")
    return out


def fix_times_rx_s(fixes: list[Fix], truth: dict[str, np.ndarray], leap_s: float = GPS_UTC_LEAP_S) -> np.ndarray:
    """Each fix's time on the truth file's t_rx_s axis: UTC seconds of day + leap seconds = GPS seconds of day,
    matched to the first truth row's GPS time of week (so midnight crossings are handled)."""
    tow0 = truth["gps_tow_s"][0]
    t0 = truth["t_rx_s"][0]
    gps_sod = np.array([f.t_sod_s for f in fixes]) + leap_s
    dt = np.mod(gps_sod - np.mod(tow0, 86400.0) + 43200.0, 86400.0) - 43200.0
    return t0 + dt


def track_errors_m(fixes: list[Fix], truth: dict[str, np.ndarray], leap_s: float = GPS_UTC_LEAP_S) -> np.ndarray:
    """Horizontal error of each fix against the truth position interpolated at the fix's time (nan outside the
    truth's time span)."""
    t_fix, t = fix_times_rx_s(fixes, truth, leap_s), truth["t_rx_s"]
    true = np.column_stack(pymap3d.geodetic2ecef(np.interp(t_fix, t, truth["lat_deg"]),
                                                 np.interp(t_fix, t, np.unwrap(truth["lon_deg"], period=360.0)),
                                                 np.interp(t_fix, t, truth["height_m"])))
    out = errors(fixes_ecef(fixes), true).horizontal_m
    return np.where((t_fix >= t[0]) & (t_fix <= t[-1]), out, np.nan)


_PATH = click.Path(path_type=Path)


@click.command(context_settings={"help_option_names": ["-h", "--help"]},
               help="Run GNSS-SDR on IQ_FILE (with its .sigmf-meta sidecar beside it, if any) and report its fixes "
                    "against a reference.")
@click.argument("iq", metavar="IQ_FILE", type=_PATH)
@click.option("--truth", "truth_path", type=_PATH,
              help="receiver truth CSV (default: <stem>.truth-receiver.csv if present)")
@click.option("--reference-lat", type=float, metavar="DEG", help="reference latitude, degrees")
@click.option("--reference-lon", type=float, metavar="DEG", help="reference longitude, degrees")
@click.option("--claimed", is_flag=True, help="reference = the attacker's claimed position in the truth file")
@click.option("--track", is_flag=True,
              help="also compare each fix with the truth position at the fix's time (moving receivers)")
# GNSS-SDR's own three item types, not semperfi's --format (cli._input_options): it reads no other layout
@click.option("--fs", "fs_hz", type=float, metavar="HZ", help="sample rate (default: from the sidecar)")
@click.option("--format", "item_type", type=click.Choice(COMPLEX_ITEM_TYPES),
              help="sample format (default: from the sidecar)")
@click.option("--if", "if_hz", type=float, metavar="HZ", help="IF, Hz (default: sidecar, else 0)")
@click.option("--out-dir", type=_PATH, help="where GNSS-SDR runs and writes (default: <stem>.gnss-sdr/)")
@click.option("--timeout", "timeout_s", type=float, metavar="S",
              help="give up after this many seconds (default: 300 + 10 x the file's duration)")
@click.option("--channels", type=int, default=12, show_default=True, help="GNSS-SDR tracking channels")
@click.option("--trop-model", type=click.Choice(TROP_MODELS), default="Saastamoinen", show_default=True)
@click.option("--iono-model", type=click.Choice(IONO_MODELS), default="Broadcast", show_default=True)
@click.option("--leap-seconds", type=float, default=GPS_UTC_LEAP_S, show_default=True,
              help="GPS - UTC used to put fixes on the truth's time axis")
def crosscheck(iq: Path, truth_path: Path | None, reference_lat: float | None, reference_lon: float | None,
               claimed: bool, track: bool, fs_hz: float | None, item_type: str | None, if_hz: float | None,
               out_dir: Path | None, timeout_s: float | None, channels: int, trop_model: str, iono_model: str,
               leap_seconds: float) -> int:
    """The exit status: 0 with at least one fix, 1 when GNSS-SDR produced none (errors raise)."""
    if (reference_lat is None) != (reference_lon is None):
        raise click.UsageError("--reference-lat and --reference-lon go together")
    if reference_lat is not None and not (-90 <= reference_lat <= 90 and -180 <= reference_lon <= 180):
        raise click.UsageError("reference latitude/longitude out of range")   # NaN too
    if not iq.is_file():
        raise CrosscheckError(f"IQ file not found: {iq}")
    params = _sidecar_params(iq)
    fs_hz = fs_hz if fs_hz is not None else params.get("fs_hz")
    item_type = item_type or params.get("item_type")
    if_hz = if_hz if if_hz is not None else params.get("if_hz", 0.0)
    if fs_hz is None or item_type is None:
        raise CrosscheckError(f"{iq}: no SigMF sidecar says the sample rate/format; give --fs and --format")
    duration_s = iq.stat().st_size / format_by_name(item_type).bytes_per_sample / fs_hz

    if truth_path is None:
        guess = iq.with_suffix("").parent / f"{iq.with_suffix('').name}.truth-receiver.csv"
        truth_path = guess if guess.is_file() else None
    truth = read_truth(truth_path) if truth_path is not None else None

    if reference_lat is not None:
        ref, ref_what = (reference_lat, reference_lon), "given on the command line"
    elif claimed:
        if truth is None:
            raise CrosscheckError("--claimed needs a truth file (--truth)")
        ok = np.flatnonzero(np.isfinite(truth["claimed_lat_deg"]) & np.isfinite(truth["claimed_lon_deg"]))
        if ok.size == 0:
            raise CrosscheckError(f"{truth_path}: no claimed (attacker) position in the truth file")
        k = int(ok[0])
        ref, ref_what = (truth["claimed_lat_deg"][k], truth["claimed_lon_deg"][k]), "attacker's claimed position"
    elif truth is not None:
        ref, ref_what = (truth["lat_deg"][0], truth["lon_deg"][0]), f"first row of {truth_path.name}"
    else:
        raise CrosscheckError("no reference: give --truth or --reference-lat/--reference-lon")
    if track and truth is None:
        raise CrosscheckError("--track needs a truth file (--truth)")

    out_dir = out_dir or iq.with_suffix("").parent / f"{iq.with_suffix('').name}.gnss-sdr"
    timeout_s = timeout_s if timeout_s is not None else 300.0 + 10.0 * duration_s
    version = gnss_sdr_version()
    print(f"{version}: {iq} ({duration_s:.1f} s of {item_type} at {fs_hz / 1e6:g} MSa/s, IF {if_hz:g} Hz)",
          flush=True)
    t_start = time.monotonic()
    fixes = run_gnss_sdr(iq, fs_hz, item_type, if_hz, out_dir, timeout_s, channels=channels,
                         trop_model=trop_model, iono_model=iono_model)
    run_s = time.monotonic() - t_start
    print(f"GNSS-SDR ran {run_s:.1f} s; its output is in {out_dir}")
    if not fixes:
        print(f"crosscheck: GNSS-SDR produced no fix from {iq} (log: {out_dir / LOG_NAME})", file=sys.stderr)
        return 1

    n_sats = np.array([f.n_sats for f in fixes])
    print(f"fixes: {len(fixes)}  (satellites used: median {int(np.median(n_sats))}, "
          f"min {n_sats.min()}, max {n_sats.max()})")
    first = fixes[0]
    line = f"first fix: {first.t_utc} UTC"
    if truth is not None:
        t_rx = fix_times_rx_s([first], truth, leap_seconds)[0]
        line += f"  ({t_rx:.1f} s after the start of the file, taking GPS - UTC = {leap_seconds:g} s)"
    print(line)
    last = fixes[-1]
    print(f"last fix:  {last.t_utc} UTC  at {last.lat_deg:.7f}, {last.lon_deg:.7f}, {last.height_m:.1f} m")
    errors = horizontal_errors_m(fixes, ref[0], ref[1])
    s = error_summary_m(errors)
    print(f"reference: {ref[0]:.7f}, {ref[1]:.7f} ({ref_what})")
    print(f"horizontal error vs reference [m]: mean {s['mean']:.2f}  p95 {s['p95']:.2f}  max {s['max']:.2f}")
    if track:
        te = track_errors_m(fixes, truth, leap_seconds)
        inside = te[np.isfinite(te)]
        if inside.size:
            s = error_summary_m(inside)
            print(f"horizontal error vs truth track [m]: mean {s['mean']:.2f}  p95 {s['p95']:.2f}  "
                  f"max {s['max']:.2f}  ({inside.size} of {len(fixes)} fixes inside the truth's time span)")
        else:
            print("horizontal error vs truth track: no fix falls inside the truth's time span "
                  "(check --leap-seconds)")
    return 0


def main(argv: list[str] | None = None) -> int:
    """The command line: what goes wrong, a mistyped option as much as a failed run, is one line on stderr and
    exit status 2 (click's usage block and tracebacks are not for a user)."""
    try:
        return crosscheck.main(argv, prog_name="crosscheck-gnss-sdr", standalone_mode=False)
    except click.UsageError as exc:
        why = f"{exc.format_message()} (--help says more)"
    except click.ClickException as exc:
        why = exc.format_message()
    except (CrosscheckError, RuntimeError, TimeoutError, ValueError, OSError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    except (click.exceptions.Abort, KeyboardInterrupt):
        print("crosscheck: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f"crosscheck: error: {why}", file=sys.stderr)
    return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())

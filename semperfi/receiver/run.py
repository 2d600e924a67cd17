"""`semperfi run`: the receiver over a recording or a live stream, with a live channel table and outputs flushed as
they come."""

import sys
import time
from datetime import datetime
from dataclasses import dataclass
from pathlib import Path

from .. import config
from ..errors import NoSignal, log_internal_error
from ..gps import GpsTime
from ..iq import SampleSource, SourceError, chunk_seconds, open_source
from .chain import Receiver, RunStats
from .config import SECTIONS
from .navigation import AssistedNav
from .outputs import OutputWriter, write_config
from .types import Fix


@dataclass(frozen=True)
class RunSummary:
    stats: RunStats
    last_fix: Fix | None
    duration_s: float
    wall_s: float
    truncated_bytes: int
    out_dir: Path
    input_error: str | None = None   # the input failed part-way (closed, stalled): what came before is processed
    internal_error: str | None = None   # a bug stopped the run: what came before is written, the event says where
    interrupted: bool = False           # Ctrl-C: what came before is written
    missing_s: float = 0.0              # of the --duration asked for, what the input ended before
    defence: str | None = None          # what the defence saw, in one line (None: no attack seen, or no defence)


def _live_table(receiver: Receiver, t_s: float, total_s: float | None = None):
    from rich.table import Table
    of = f" of {total_s:.1f} s ({100 * t_s / total_s:3.0f} %)" if total_s else ""
    table = Table(title=f"t = {t_s:7.1f} s{of}   fixes {receiver.stats.n_fixes}", title_justify="left")
    for col in ("PRN", "state", "C/N0", "Doppler [Hz]", "code [chips]", "subframes"):
        table.add_column(col, justify="right")
    for r in receiver.channel_rows():
        table.add_row(str(r.prn), r.state, f"{r.cn0_dbhz:5.1f}", f"{r.doppler_hz:8.1f}", f"{r.code_phase_chips:7.3f}",
                      str(r.subframes))
    return table


def run_file(path: str | Path, fmt: str | None, fs_hz: float | None, if_hz: float | None, cfg: dict,
             out_dir: str | Path, nav_path: str | None = None, live: bool = False, receiver_hook=None,
             receiver_factory=Receiver, skip_s: float = 0.0, duration_s: float | None = None,
             fs_out_hz: float | None = None, stop=None, fix_streams=()) -> RunSummary:
    """Run a receiver over a file, `-` (standard input) or rtl_tcp://HOST:PORT; ValueError (one line) for bad input,
    NoSignal when nothing acquires. skip_s, duration_s cut a window; fs_out_hz decimates to a processing rate.

    receiver_factory builds the receiver (the conventional chain by default; the defended one wraps it);
    stop(receiver) -> bool, asked after each chunk, ends the run early (a harness that wants only the first fix);
    fix_streams (fix_stream.FixStream: an autopilot's GPS_INPUT, NMEA to a port) get every fix too."""
    source = open_source(path, fmt, fs_hz, if_hz, skip_s=skip_s, duration_s=duration_s, fs_out_hz=fs_out_hz)
    assisted = AssistedNav.from_rinex(nav_path) if nav_path else None
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_config(out_dir, config.dumps_toml(cfg, SECTIONS))
    t0 = time.perf_counter()
    input_error = internal_error = None
    interrupted = False
    total_s = None if source.expected_samples is None else source.expected_samples / source.fs_hz
    with OutputWriter(out_dir, cfg["output"]["formats"]) as out:
        written: Fix | None = None   # the last fix as written: labelled by the defence, when there is one

        def on_fix(fix: Fix) -> None:
            nonlocal written
            written = fix
            out.write(fix)
            for stream in fix_streams:
                stream.update(fix)

        receiver = receiver_factory(cfg, source.fs_hz, source.if_hz, assisted, on_fix=on_fix, events=_Loud(out),
                                    week_hint=_week_hint(source, assisted), on_observations=out.write_observations)
        if receiver_hook is not None:
            receiver_hook(receiver)
        out.emit("input", 0.0, source=source.name, format=source.fmt.name, fs_hz=source.fs_in_hz,
                 if_hz=source.if_in_hz, skip_s=source.skip_samples / source.fs_in_hz, processing_fs_hz=source.fs_hz,
                 processing_if_hz=source.if_hz)
        live_ctx = None
        if live:
            from rich.console import Console
            from rich.live import Live
            live_ctx = Live(_live_table(receiver, 0.0, total_s), console=Console(file=sys.stderr),
                            refresh_per_second=4)
            live_ctx.start()
        try:
            last_draw = 0.0
            interference = None
            for chunk in source.chunks(chunk_seconds(source.fs_hz)):
                receiver.feed(chunk)
                _report_notices(source, out)
                if receiver.interference.now != interference:
                    interference = receiver.interference.now
                    if interference:
                        print(f"warning at t = {receiver.stats.samples / source.fs_hz:.1f} s: {interference}",
                              file=sys.stderr)
                if stop is not None and stop(receiver):
                    break
                now = time.perf_counter()
                if live_ctx is not None and now - last_draw > 0.25:
                    live_ctx.update(_live_table(receiver, receiver.stats.samples / source.fs_hz, total_s))
                    last_draw = now
        except KeyboardInterrupt:
            interrupted = True
            out.emit("interrupted", receiver.stats.samples / source.fs_hz)
        except SourceError as exc:   # keep everything computed; the caller reports the failure after the summary
            input_error = str(exc)
            out.emit("input_lost", receiver.stats.samples / source.fs_hz, error=input_error)
        except Exception as exc:     # a bug: never a traceback; everything written so far is kept
            internal_error = log_internal_error(out, receiver.stats.samples / source.fs_hz, exc)
        finally:
            source.close()
            if source.truncated_bytes:
                out.emit("truncated_input", source.n_samples / source.fs_hz, dropped_bytes=source.truncated_bytes)
            if hasattr(receiver, "finish") and internal_error is None:
                try:
                    receiver.finish()
                except Exception as exc:
                    internal_error = log_internal_error(out, receiver.stats.samples / source.fs_hz, exc)
            if live_ctx is not None:
                live_ctx.update(_live_table(receiver, receiver.stats.samples / source.fs_hz, total_s))
                live_ctx.stop()
    guard = getattr(receiver, "guard", None)
    summary = RunSummary(receiver.stats, written or receiver.last_fix, source.n_samples / source.fs_hz,
                         time.perf_counter() - t0, source.truncated_bytes, out_dir, input_error, internal_error,
                         interrupted, source.missing_s, guard.account() if guard is not None else None)
    if source.nonfinite_samples:
        print(f"warning: {source.nonfinite_samples} samples were NaN or infinite and were zeroed", file=sys.stderr)
    if not receiver.stats.confirmed and input_error is None and internal_error is None and not interrupted:
        if source.n_samples == 0:
            raise NoSignal(f"{source.name} held no samples; outputs in {out_dir}")
        if receiver.interference.now:
            raise NoSignal(f"no satellite signal could be tracked in {source.name} under its "
                           f"{receiver.interference.now}; outputs in {out_dir}")
        acquired = sorted(receiver.stats.acquired)
        seen = f" (acquired, none to bit synchronisation: PRNs {' '.join(map(str, acquired))})" if acquired else ""
        short = f"; {source.n_samples / source.fs_hz:.1f} s is too short to track (bit synchronisation needs a few " \
            f"seconds)" if acquired and source.n_samples < SHORT_S * source.fs_hz else ""
        raise NoSignal(f"no satellite signal could be tracked in {source.name}{seen}: check --fs "
                       f"({source.fs_in_hz:g} Hz), --format ({source.fmt.name}) and --if ({source.if_in_hz:g} Hz)"
                       f"{short}; outputs in {out_dir}")
    return summary


SHORT_S = 5.0   # a recording shorter than this may hold satellites that never reach bit synchronisation


class _Loud:
    """The event log, with what a user must hear of as it happens (the flight side's link lost or flooding it, a
    maneuver that failed) also on stderr."""

    LOUD = ("link_lost", "link_rejected", "maneuver_failed")

    def __init__(self, out: OutputWriter):
        self.out = out

    def emit(self, kind: str, t_s: float, **fields) -> None:
        self.out.emit(kind, t_s, **fields)
        if kind in self.LOUD:
            print(f"warning at t = {t_s:.1f} s: {fields.get('why', kind)}", file=sys.stderr)


def _report_notices(source: SampleSource, out: OutputWriter) -> None:
    """A live stream's trouble goes to events.jsonl and, as it happens, to stderr."""
    while source.notices:
        n = source.notices.pop(0)
        out.emit(n.kind, n.t_s, **n.fields)
        print(f"warning at t = {n.t_s:.1f} s: {n.fields.get('why', n.kind)}", file=sys.stderr)


def _week_hint(source, assisted: AssistedNav | None) -> int | None:
    """The GPS week, when the sidecar's capture time or the navigation file tells it (the message's WN is 10 bits)."""
    when = source.sidecar.datetime_utc if source.sidecar is not None else None
    if when:
        try:
            return GpsTime.from_datetime(datetime.fromisoformat(str(when).replace("Z", "+00:00"))).week
        except ValueError:
            pass
    if assisted is not None and assisted.ephemerides:   # the week most of the file's ephemerides are in
        weeks = [e.week for e in assisted.ephemerides]
        return max(set(weeks), key=weeks.count)
    return None

"""`semperfi run`: the receiver over a recorded file, with a live channel table and outputs flushed as they come."""

import sys
import time
from datetime import datetime
from dataclasses import dataclass
from pathlib import Path

from .. import config
from ..gps.time import GpsTime
from ..iq import open_iq
from .chain import Receiver, RunStats
from .config import DEFAULTS
from .navigation import AssistedNav
from .outputs import OutputWriter, write_config
from .types import Fix

CHUNK_S = 0.1


class NoSignal(ValueError):
    """Nothing could be acquired: almost always a wrong sample rate, format or IF."""


@dataclass(frozen=True)
class RunSummary:
    stats: RunStats
    last_fix: Fix | None
    duration_s: float
    wall_s: float
    truncated_bytes: int
    out_dir: Path


def _live_table(receiver: Receiver, t_s: float):
    from rich.table import Table
    table = Table(title=f"t = {t_s:7.1f} s   fixes {receiver.stats.n_fixes}", title_justify="left")
    for col in ("PRN", "state", "C/N0", "Doppler [Hz]", "code [chips]", "subframes"):
        table.add_column(col, justify="right")
    for r in receiver.channel_rows():
        table.add_row(str(r.prn), r.state, f"{r.cn0_dbhz:5.1f}", f"{r.doppler_hz:8.1f}", f"{r.code_phase_chips:7.3f}",
                      str(r.subframes))
    return table


def run_file(path: str | Path, fmt: str | None, fs_hz: float | None, if_hz: float | None, cfg: dict,
             out_dir: str | Path, nav_path: str | None = None, live: bool = False, receiver_hook=None,
             receiver_factory=Receiver) -> RunSummary:
    """Run a receiver over a file; ValueError (one line) for bad input, NoSignal when nothing acquires.

    receiver_factory builds the receiver (the conventional chain by default; the defended one wraps it)."""
    reader = open_iq(path, fmt, fs_hz, if_hz)
    reader.chunk_samples = int(round(reader.fs_hz * CHUNK_S))   # the rate may come from the sidecar
    assisted = AssistedNav.from_rinex(nav_path) if nav_path else None
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_config(out_dir, config.dumps_toml(cfg))
    t0 = time.perf_counter()
    with OutputWriter(out_dir, cfg["output"]["formats"]) as out:
        receiver = receiver_factory(cfg, reader.fs_hz, reader.if_hz, assisted, on_fix=out.write, events=out,
                                    week_hint=_week_hint(reader, assisted), on_observations=out.write_observations)
        if receiver_hook is not None:
            receiver_hook(receiver)
        if reader.truncated_bytes:
            out.emit("truncated_input", reader.n_samples / reader.fs_hz, dropped_bytes=reader.truncated_bytes)
        live_ctx = None
        if live:
            from rich.console import Console
            from rich.live import Live
            live_ctx = Live(_live_table(receiver, 0.0), console=Console(file=sys.stderr), refresh_per_second=4)
            live_ctx.start()
        try:
            last_draw = 0.0
            for chunk in reader:
                receiver.feed(chunk)
                now = time.perf_counter()
                if live_ctx is not None and now - last_draw > 0.25:
                    live_ctx.update(_live_table(receiver, receiver.stats.samples / reader.fs_hz))
                    last_draw = now
        except KeyboardInterrupt:
            out.emit("interrupted", receiver.stats.samples / reader.fs_hz)
        finally:
            if hasattr(receiver, "finish"):
                receiver.finish()
            if live_ctx is not None:
                live_ctx.update(_live_table(receiver, receiver.stats.samples / reader.fs_hz))
                live_ctx.stop()
    summary = RunSummary(receiver.stats, receiver.last_fix, reader.n_samples / reader.fs_hz,
                         time.perf_counter() - t0, reader.truncated_bytes, out_dir)
    if not receiver.stats.confirmed:
        raise NoSignal(f"no satellite signal could be tracked in {path}: check --fs ({reader.fs_hz:g} Hz), --format "
                       f"({reader.fmt.name}) and --if ({reader.if_hz:g} Hz); outputs in {out_dir}")
    return summary


def _week_hint(reader, assisted: AssistedNav | None) -> int | None:
    """The GPS week, when the sidecar's capture time or the navigation file tells it (the message's WN is 10 bits)."""
    when = reader.sidecar.datetime_utc if reader.sidecar is not None else None
    if when:
        try:
            return GpsTime.from_datetime(datetime.fromisoformat(str(when).replace("Z", "+00:00"))).week
        except ValueError:
            pass
    if assisted is not None and assisted.ephemerides:   # the week most of the file's ephemerides are in
        weeks = [e.week for e in assisted.ephemerides]
        return max(set(weeks), key=weeks.count)
    return None


def load_receiver_config(path=None, sets=()) -> dict:
    return config.load(DEFAULTS, path, sets)

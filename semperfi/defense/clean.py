"""The plug-in filter: spoofed IQ in, spoofer-free IQ out, same format and rate, for any unmodified receiver."""

import time
from dataclasses import dataclass
from pathlib import Path

from .. import config
from ..errors import log_internal_error
from ..iq import GR_COMPLEX, IBYTE, ISHORT, IqWriter, SourceError, chunk_seconds, open_source
from ..progress import progress as show_progress
from ..receiver import EventLog, Monitor
from .guard import SpoofGuard


@dataclass(frozen=True)
class CleanSummary:
    out_path: Path
    duration_s: float
    wall_s: float
    alarms: tuple[int, ...]
    cancelled: tuple[int, ...]
    verified: tuple[int, ...]
    gave_up: dict
    attenuation_db: dict
    clipped_fraction: float
    input_error: str | None = None
    internal_error: str | None = None
    interrupted: bool = False          # Ctrl-C: what was cleaned before it is written
    satellites: tuple[int, ...] = ()   # PRNs whose signals the guard's searches found at all
    truncated_bytes: int = 0           # the input ended mid-sample
    missing_s: float = 0.0             # of the --duration asked for, what the input ended before
    interference: str | None = None    # what the input held besides GPS at the end, if anything
    removed: tuple[int, ...] = ()      # PRNs given up and taken out whole: the output leaves them out
    remnants: tuple[int, ...] = ()     # PRNs whose spoofer's remnant is taken out, their legitimate signals kept


def clean_file(in_path, out_path, fmt, fs_hz, if_hz, cfg: dict, events_path=None, progress: bool = False,
               skip_s: float = 0.0, duration_s: float | None = None, fs_out_hz: float | None = None) -> CleanSummary:
    """Stream IN (a file, `-` or rtl_tcp://HOST:PORT) through the spoof guard into OUT (with its SigMF sidecar);
    events go to events_path. OUT keeps IN's format and rate, except after decimation (fs_out_hz) or from packed
    samples, where it is complex integers of at least IN's width at the processing rate."""
    source = open_source(in_path, fmt, fs_hz, if_hz, skip_s=skip_s, duration_s=duration_s, fs_out_hz=fs_out_hz)
    out_path = Path(out_path)
    if str(in_path) != "-" and not str(in_path).startswith("rtl_tcp://") and \
            out_path.resolve() == Path(in_path).resolve():
        raise ValueError("the output would overwrite the input: choose another -o")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    events_path = Path(events_path) if events_path else out_path.with_suffix(".events.jsonl")
    t0 = time.perf_counter()
    input_error = internal_error = None
    interrupted = False
    with EventLog(events_path) as events, IqWriter(
            out_path, _output_format(source), source.fs_hz, if_hz=source.if_hz,
            metadata={"cleaned_from": source.name, "configuration": config.dumps_toml(cfg),
                      "skip_s": source.skip_samples / source.fs_in_hz},
            description="SemperFi plug-in filter output (spoofing signals cancelled)") as writer:
        guard = SpoofGuard(cfg, source.fs_hz, source.if_hz, events, real_samples=source.real_valued,
                           remove_given_up=True, replay_start=True)
        monitor = Monitor(source.fs_hz, source.if_hz, events.emit)
        chunk_s = chunk_seconds(source.fs_hz)
        chunks = source.chunks(chunk_s)
        total = source.expected_samples
        chunks = show_progress(chunks, None if total is None else -(-total // int(source.fs_hz * chunk_s)),
                               "cleaning", progress)
        try:
            for chunk in chunks:
                monitor.push(chunk)
                writer.write(guard.push(chunk))
        except KeyboardInterrupt:
            interrupted = True
            events.emit("interrupted", source.n_samples / source.fs_hz)
        except SourceError as exc:
            input_error = str(exc)
            events.emit("input_lost", source.n_samples / source.fs_hz, error=input_error)
        except Exception as exc:   # a bug: never a traceback; the samples cleaned so far are kept
            internal_error = log_internal_error(events, source.n_samples / source.fs_hz, exc)
        finally:   # whatever happened, the samples already cleaned reach the file, in order
            source.close()
            try:
                writer.write(guard.flush())
                guard.finish()
            except Exception as exc:
                internal_error = internal_error or log_internal_error(events, source.n_samples / source.fs_hz, exc)
            # the sidecar says which satellites the output leaves out (given up, taken out whole)
            writer.annotate("removed_prns", sorted(guard.removed))
        clipped = writer.clipped_fraction
    return CleanSummary(out_path, source.n_samples / source.fs_hz, time.perf_counter() - t0,
                        tuple(sorted(guard.alarmed_prns)), tuple(sorted(guard.cancel_started)),
                        tuple(sorted(guard.verified)), dict(guard.gave_up), guard.canceller.report(), clipped,
                        input_error, internal_error, interrupted, satellites=tuple(sorted(guard.present_prns)),
                        truncated_bytes=source.truncated_bytes, missing_s=source.missing_s,
                        interference=monitor.watch.now, removed=tuple(sorted(guard.removed)),
                        remnants=tuple(sorted(guard.remnants)))


def _output_format(source):
    """IN's format where it can carry the cleaned signal, else complex integers as wide (int8 or int16)."""
    fmt = source.fmt
    if source.factor == 1 and not fmt.bits:
        return fmt
    if not fmt.is_integer:
        return GR_COMPLEX
    return IBYTE if fmt.bits or fmt.item_dtype.itemsize == 1 else ISHORT

"""The plug-in filter: spoofed IQ in, spoofer-free IQ out, same format and rate, for any unmodified receiver."""

import time
from dataclasses import dataclass
from pathlib import Path

from .. import config
from ..iq import IqWriter, open_iq
from ..receiver.outputs import EventLog
from .guard import SpoofGuard

CHUNK_S = 0.1


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


def clean_file(in_path, out_path, fmt, fs_hz, if_hz, cfg: dict, events_path=None, progress: bool = False) -> CleanSummary:
    """Stream IN through the spoof guard into OUT (with its SigMF sidecar); events go to events_path."""
    reader = open_iq(in_path, fmt, fs_hz, if_hz)
    reader.chunk_samples = int(round(reader.fs_hz * CHUNK_S))
    out_path = Path(out_path)
    if out_path.resolve() == Path(in_path).resolve():
        raise ValueError("the output would overwrite the input: choose another -o")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    events_path = Path(events_path) if events_path else out_path.with_suffix(".events.jsonl")
    t0 = time.perf_counter()
    with EventLog(events_path) as events, IqWriter(
            out_path, reader.fmt, reader.fs_hz, if_hz=reader.if_hz,
            metadata={"cleaned_from": Path(in_path).name, "configuration": config.dumps_toml(cfg)},
            description="SemperFi plug-in filter output (spoofing signals cancelled)") as writer:
        guard = SpoofGuard(cfg, reader.fs_hz, reader.if_hz, events)
        chunks = reader
        if progress:
            from tqdm import tqdm
            chunks = tqdm(reader, total=-(-reader.n_samples // reader.chunk_samples), unit="chunk", desc="cleaning")
        try:
            for chunk in chunks:
                writer.write(guard.push(chunk))
        finally:   # whatever happened, the samples already cleaned reach the file, in order
            writer.write(guard.flush())
            guard.finish()
        clipped = writer.clipped_fraction
    return CleanSummary(out_path, reader.n_samples / reader.fs_hz, time.perf_counter() - t0,
                        tuple(sorted(guard.alarmed_prns)), tuple(sorted(guard.cancel_started)),
                        tuple(sorted(guard.verified)), dict(guard.gave_up), guard.canceller.report(), clipped)

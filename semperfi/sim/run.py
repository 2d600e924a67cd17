"""Simulate a scenario into an IQ file with its SigMF sidecar, truth log and effective configuration."""

from dataclasses import dataclass
from pathlib import Path

from .. import config
from ..iq import IqWriter
from ..progress import progress as show_progress
from .scenario import SECTIONS
from .simulate import Simulator
from .truth import TruthLog, truth_paths


@dataclass(frozen=True)
class SimSummary:
    out_path: Path
    duration_s: float
    fs_hz: float
    fmt: str
    legit_prns: tuple[int, ...]
    spoofed_prns: tuple[int, ...]
    clipped_fraction: float
    start_utc: str


def simulate_to_file(cfg: dict, out_path: str | Path, progress: bool = False) -> SimSummary:
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    sim = Simulator(cfg)
    s = cfg["signal"]
    stem = out_path.with_suffix("")
    (stem.parent / f"{stem.name}.scenario.toml").write_text(config.dumps_toml(cfg, SECTIONS))
    truth = TruthLog(out_path)
    meta = {"scenario": f"{stem.name}.scenario.toml", "truth": {k: p.name for k, p in truth_paths(out_path).items()},
            "gps_week": sim.t0.week, "gps_tow_s": sim.t0.tow_s, "noise_rms": sim.noise_rms}
    n_chunks = -(-sim.n_samples // sim.chunk_samples)
    try:
        with IqWriter(out_path, s["format"], sim.fs_hz, if_hz=sim.if_hz, metadata=meta,
                      description="SemperFi simulated GPS L1 C/A", datetime_utc=sim.t0.to_datetime().isoformat()) as w:
            for chunk in show_progress(sim.chunks(truth.record, 1.0 / cfg["output"]["truth_rate_hz"], truth.event),
                                       n_chunks, "simulating", progress):
                w.write(chunk)
            clipped = w.clipped_fraction
    finally:
        truth.close()
    return SimSummary(out_path, sim.n_samples / sim.fs_hz, sim.fs_hz, s["format"],
                      tuple(x.prn for x in sim.signals if x.source == "legit"),
                      tuple(x.prn for x in sim.signals if x.source == "spoof"), clipped,
                      f"{sim.t0.to_datetime():%Y-%m-%d %H:%M:%S} GPST")

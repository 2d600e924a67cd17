"""`semperfi demo`: the built-in scenario end to end. Today: simulate an attack, then look at it with acquisition."""

from pathlib import Path
from typing import Iterator

import numpy as np

from ..iq import open_iq
from ..receiver.acquisition import DopplerGrid, acquire
from ..receiver.plots import plot_cafs
from ..sim.run import simulate_to_file
from ..sim.scenario import load_scenario
from ..sim.truth import read_signal_truth, truth_paths

DEMO_SETTINGS = ["attacker.enabled=true", "attacker.power_advantage_db=6.0", "attacker.offset_east_m=1000.0",
                 "signal.fs_hz=4e6", 'signal.format="ishort"']


def _chips_apart(a: float, b: float) -> float:
    return abs((a - b + 511.5) % 1023 - 511.5)


def run_demo(out_dir: str | Path, duration_s: float, sets: list[str], progress: bool = False) -> Iterator[str]:
    out_dir = Path(out_dir)
    cfg = load_scenario(None, DEMO_SETTINGS + [f"time.duration_s={duration_s}"] + sets)
    out = out_dir / "scenario.bin"
    summary = simulate_to_file(cfg, out, progress=progress)
    yield (f"simulated {summary.duration_s:g} s at {summary.fs_hz / 1e6:g} MSa/s ({summary.fmt}) from "
           f"{summary.start_utc} into {out}")
    yield f"  legitimate PRNs {' '.join(map(str, summary.legit_prns))}; spoofed PRNs {' '.join(map(str, summary.spoofed_prns))}"
    truth = [r for r in read_signal_truth(truth_paths(out)["signals.csv"]) if r["t_rx_s"] == 0.0]
    reader = open_iq(out)
    cafs = acquire(reader.read(0, int(reader.fs_hz * 0.01)), reader.fs_hz, summary.legit_prns,
                   DopplerGrid(max_hz=6000.0, step_hz=333.0), reader.if_hz, coherent_ms=2, noncoherent=5)
    found_legit = found_spoof = 0
    for prn, caf in cafs.items():
        for source in ("legit", "spoof"):
            t = next((r for r in truth if r["prn"] == prn and r["source"] == source), None)
            if t and any(_chips_apart(p.code_phase_chips, t["code_phase_chips"]) < 0.25 for p in caf.peaks):
                found_legit += source == "legit"
                found_spoof += source == "spoof"
    plot_cafs([c for c in cafs.values() if c.best], out_dir / "acquisition.png", "acquisition of the spoofed scenario")
    yield (f"acquisition sees {found_legit}/{len(summary.legit_prns)} legitimate and {found_spoof}/"
           f"{len(summary.spoofed_prns)} spoofed peaks at their true code phases (within 0.25 chip)")
    strongest_spoofed = sum(1 for prn, caf in cafs.items() if caf.best and any(
        r["prn"] == prn and r["source"] == "spoof" and _chips_apart(caf.best.code_phase_chips, r["code_phase_chips"]) < 0.25
        for r in truth))
    yield (f"a conventional receiver would lock on the spoofer for {strongest_spoofed} PRNs "
           f"(the strongest peak is the attacker's); CAF plot: {out_dir / 'acquisition.png'}")
    yield f"truth: {', '.join(str(p) for p in truth_paths(out).values())}"

"""The paper's IQ figure: the retrieved legitimate signals' prompt correlations (1 ms, after cancellation) as a
scatter in the I/Q plane, per attacker power, with what they cost the navigation message (parity errors)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..defense import DefendedReceiver, load_config
from ..receiver import run_file
from .xgen import RECEIVER_SETTINGS, Case, prepare

SCATTER_MS = 2000      # the last two seconds of each channel's prompts


@dataclass
class Symbols:
    advantage_db: float
    prompts: dict[int, np.ndarray]    # PRN -> the last SCATTER_MS prompts, rotated and scaled: bits at +-1 on I
    bit_snr_db: dict[int, float]      # PRN -> 20 ms soft bits: mean^2 / variance of |I|
    subframes: dict[int, tuple[int, int]]   # PRN -> (subframes read, subframes failing parity) after cancellation


def recovered_symbols(case: Case, nav_path: str | Path, work: Path) -> Symbols:
    """Run the defended receiver on a cross-generator case; the prompts of every PRN whose spoofer was cancelled."""
    data = prepare(case, nav_path, work)
    out = work / f"{case.tag}-symbols"
    made: list[DefendedReceiver] = []

    def factory(*args, **kwargs):
        made.append(DefendedReceiver(*args, **kwargs))
        return made[-1]

    run_file(data, None, None, None, load_config(None, ['defense.mode="full"', *RECEIVER_SETTINGS]), out,
             str(nav_path), receiver_factory=factory)
    rx = made[0]
    events = [json.loads(line) for line in open(out / "events.jsonl")]
    prompts, snr, subframes = {}, {}, {}
    for prn, t_cancel in sorted(rx.guard.cancel_started.items()):
        ch = rx.inner.channels.get(prn)
        if ch is None or ch.ms < SCATTER_MS or ch.bits.edge_ms is None:
            continue
        p = ch.prompt[np.arange(ch.ms - SCATTER_MS, ch.ms) % ch.HISTORY_MS]
        p = p * np.exp(-1j * np.angle(np.mean(p ** 2)) / 2)       # the Costas loop's phase, bits on the I axis
        p = p / np.mean(np.abs(p.real))
        prompts[prn] = p
        first = (ch.bits.edge_ms - (ch.ms - SCATTER_MS)) % 20
        n_bits = (SCATTER_MS - first) // 20
        bits = np.abs(p.real[first:first + 20 * n_bits].reshape(n_bits, 20).sum(axis=1))
        snr[prn] = round(float(10 * np.log10(np.mean(bits) ** 2 / max(np.var(bits), 1e-12))), 1)
        read = [e for e in events if e["event"] == "subframe" and e["prn"] == prn and e["t_rx_s"] > t_cancel]
        subframes[prn] = (len(read), sum(e["parity_errors"] > 0 for e in read))
    return Symbols(case.advantage_db, prompts, snr, subframes)


def plot_symbols(results: list[Symbols], path: str | Path) -> None:
    """One panel per attacker power: every retrieved PRN's last 2 s of prompts."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(3.0 * len(results), 3.2), squeeze=False)
    for ax, r in zip(axes[0], results):
        for prn, p in r.prompts.items():
            ax.scatter(p.real, p.imag, s=1, alpha=0.3, label=f"PRN {prn}")
        read = sum(n for n, _ in r.subframes.values())
        bad = sum(b for _, b in r.subframes.values())
        median = np.median(list(r.bit_snr_db.values())) if r.bit_snr_db else float("nan")
        ax.set_title(f"+{r.advantage_db:g} dB: bit SNR {median:.1f} dB\n{bad}/{read} subframes failing parity",
                     fontsize=8)
        ax.set_xlim(-4, 4)
        ax.set_ylim(-4, 4)
        ax.set_aspect("equal")
        ax.set_xlabel("I", fontsize=7)
        ax.set_ylabel("Q", fontsize=7)
        ax.tick_params(labelsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)

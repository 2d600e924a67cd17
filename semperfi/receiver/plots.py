"""Pictures of what acquisition saw (matplotlib, imported only when a plot is asked for)."""

import numpy as np


def plot_cafs(cafs, path, title: str = "") -> None:
    """One panel per PRN: the CAF's code-phase cut at the strongest Doppler row, every reported peak marked."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cafs = list(cafs)
    if not cafs:
        raise ValueError("nothing to plot: no PRN was acquired")
    cols = min(4, len(cafs))
    rows = -(-len(cafs) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.4 * rows), squeeze=False)
    for ax, caf in zip(axes.flat, cafs):
        row = int(np.argmax(caf.power.max(axis=1)))
        ax.plot(caf.code_phase_chips, caf.power[row], lw=0.6)
        for p in caf.peaks:
            ax.axvline(p.code_phase_chips, color="r", lw=0.5, alpha=0.5)
        ax.axhline(caf.threshold, color="k", ls=":", lw=0.6)
        ax.set_title(f"PRN {caf.prn}  {caf.doppler_hz[row]:.0f} Hz", fontsize=8)
        ax.set_xlabel("code phase [chips]", fontsize=7)
        ax.tick_params(labelsize=6)
    for ax in list(axes.flat)[len(cafs):]:
        ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

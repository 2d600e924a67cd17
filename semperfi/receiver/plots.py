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


def plot_before_after(before, after, marks: dict, path, title: str = "", half_width_chips: float = 4.0) -> None:
    """One column per PRN, its CAF (the maximum over Doppler at each code phase) before (top) and after (bottom)
    cancellation, on one scale per column, zoomed on the peaks. marks: PRN -> (spoofer's code phase, legitimate
    code phase or None), in chips, as the receiver identified them."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    prns = [c.prn for c in before]
    if not prns:
        raise ValueError("nothing to plot: no PRN was cancelled")
    fig, axes = plt.subplots(2, len(prns), figsize=(3.0 * len(prns), 4.6), squeeze=False, sharey="col")
    for col, (b, a) in enumerate(zip(before, after)):
        spoof, legit = marks[b.prn]
        center = spoof if legit is None else spoof + ((legit - spoof + 511.5) % 1023 - 511.5) / 2
        for row, caf in enumerate((b, a)):
            ax = axes[row, col]
            rel = (caf.code_phase_chips - center + 511.5) % 1023 - 511.5
            keep = np.abs(rel) <= half_width_chips
            order = np.argsort(rel[keep])
            ax.plot(rel[keep][order], caf.power.max(axis=0)[keep][order], lw=0.9, color="0.2")
            ax.axvline((spoof - center + 511.5) % 1023 - 511.5, color="tab:red", ls="--", lw=0.9, label="spoofer")
            if legit is not None:
                ax.axvline((legit - center + 511.5) % 1023 - 511.5, color="tab:green", ls="--", lw=0.9,
                           label="legitimate")
            ax.axhline(caf.threshold, color="k", ls=":", lw=0.6)
            ax.tick_params(labelsize=7)
            if row == 0:
                sep = "" if legit is None else f", {abs((legit - spoof + 511.5) % 1023 - 511.5) * 977.5:.0f} ns apart"
                ax.set_title(f"PRN {b.prn}{sep}", fontsize=8)
            else:
                ax.set_xlabel("code phase - centre [chips]", fontsize=7)
            if col == 0:
                ax.set_ylabel(("before" if row == 0 else "after") + " cancellation\n|R|^2 / noise", fontsize=7)
    axes[0, 0].legend(fontsize=6, loc="upper right")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

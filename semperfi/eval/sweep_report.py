"""A sweep's results table as a report a person would rather look at than read: DIR/report.html with its PNG
figures beside it (availability, accuracy and verdict-to-recovered latency against attacker power, per attack kind),
the cells that crashed with the command that reproduces each, and the whole table."""

from __future__ import annotations

import html
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 -- after the backend is chosen

from .grid import COLUMNS  # noqa: E402

KIND_COLOURS = {"static": "tab:blue", "flying": "tab:green", "takeover": "tab:red", "push": "tab:purple"}
FIGURES = (("availability", "availability", "availability from the clean first fix (%)", 100.0, False),
           ("accuracy", "last_mean_m", "horizontal error, last 10 s (m)", 1.0, True),
           ("latency", "verdict_to_recovered_s", "verdict to first recovered fix (s)", 1.0, False),
           ("gap", "longest_gap_s", "longest gap without a true fix (s)", 1.0, False))


def _number(value) -> float | None:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _crashed(row: dict) -> bool:
    return str(row.get("crash")).lower() in ("true", "1") or bool(row.get("error"))


def _figure(rows: list[dict], key: str, ylabel: str, scale: float, log: bool, path: Path) -> int:
    """Key against attacker power, one colour per kind; the number of points drawn."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    drawn = 0
    for kind, colour in KIND_COLOURS.items():
        pts = [(_number(r.get("advantage_db")), _number(r.get(key))) for r in rows if r.get("kind") == kind]
        pts = [(x, y * scale) for x, y in pts if x is not None and y is not None and (y > 0 or not log)]
        if pts:
            ax.scatter(*zip(*pts), s=18, color=colour, label=f"{kind} ({len(pts)})", alpha=0.8)
            drawn += len(pts)
    if log and drawn:
        ax.set_yscale("log")
    ax.set_xlabel("attacker power over the legitimate signals (dB)")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if drawn:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no cell has this figure", ha="center", va="center", transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return drawn


def _td(value) -> str:
    return f"<td>{html.escape('' if value is None else str(value))}</td>"


def page_head(title: str) -> list[str]:
    """An HTML report's head and title, with the count of images a browser could not show."""
    return [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
            "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;font-size:12px}"
            "td,th{border:1px solid #ccc;padding:2px 6px}img{max-width:48%;margin:4px}</style>",
            # what a browser could not show, counted once the page has loaded (scripts/report-screenshot reads it)
            "<script>window.addEventListener('load', () => { document.body.dataset.missing = [...document.images]"
            ".filter(i => !i.complete || i.naturalWidth === 0).length; });</script></head>",
            "<body data-missing='unknown'>",
            f"<h1>{html.escape(title)}</h1>"]


def render_report(rows: list[dict], out_dir: str | Path, title: str = "SemperFi sweep") -> Path:
    """Write out_dir/report.html and its figures; the report's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    crashed = [r for r in rows if _crashed(r)]
    avail = [_number(r.get("availability")) for r in rows]
    avail = [a for a in avail if a is not None]
    wrong = sum(int(_number(r.get("good_but_wrong")) or 0) for r in rows)
    beyond = sum(int(_number(r.get("good_beyond_hpl")) or 0) for r in rows)
    parts = [*page_head(title),
             f"<p>{len(rows)} cells; {len(crashed)} crashed or failed; median availability "
             f"{100 * sorted(avail)[len(avail) // 2]:.1f} %; " if avail else f"<p>{len(rows)} cells; ",
             f"fixes called good but wrong (&gt; 10 m): {wrong}; beyond their HPL: {beyond}.</p>"]
    for name, key, ylabel, scale, log in FIGURES:
        png = out / f"{name}.png"
        _figure(rows, key, ylabel, scale, log, png)
        parts.append(f"<img src='{png.name}' alt='{html.escape(ylabel)}'>")
    if crashed:
        parts.append("<h2>Crashed or failed</h2><table><tr><th>cell</th><th>error</th><th>reproduce</th></tr>")
        parts += [f"<tr>{_td(r.get('cell_id'))}{_td(r.get('error'))}<td><code>{html.escape(str(r.get('repro')))}"
                  f"</code></td></tr>" for r in crashed]
        parts.append("</table>")
    keys = ["cell_id", "kind", "place", "date", "offset_m", "azimuth_deg", "advantage_db", "duration_s", "fs_hz",
            *(key for _, key in COLUMNS)]
    parts.append("<h2>All cells</h2><table><tr>" + "".join(f"<th>{html.escape(k)}</th>" for k in keys) + "</tr>")
    parts += ["<tr>" + "".join(_td(r.get(k)) for k in keys) + "</tr>" for r in rows]
    parts.append("</table></body></html>")
    report = out / "report.html"
    report.write_text("\n".join(parts))
    return report

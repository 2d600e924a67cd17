"""The `semperfi` command."""

import sys

import click

from . import __version__


def _fail(message: str) -> None:
    """A user's mistake: one line on stderr and a non-zero exit."""
    click.echo(f"semperfi: error: {message}", err=True)
    sys.exit(2)


@click.group()
@click.version_option(__version__)
def main() -> None:
    """SemperFi: a spoofer-eliminating GPS L1 C/A receiver, and the world it is proven against."""


@main.command()
@click.argument("scenario", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out_path", required=True, type=click.Path(dir_okay=False), help="IQ file to write")
@click.option("--format", "fmt", type=click.Choice(["ibyte", "ishort", "gr_complex", "cfloat"]), help="sample format")
@click.option("--fs", "fs_hz", type=float, help="sample rate, Hz")
@click.option("--if", "if_hz", type=float, help="intermediate frequency, Hz")
@click.option("--duration", "duration_s", type=float, help="seconds to simulate")
@click.option("--set", "sets", multiple=True, metavar="SECTION.KEY=VALUE", help="override a scenario key")
def sim(scenario, out_path, fmt, fs_hz, if_hz, duration_s, sets) -> None:
    """Simulate GPS L1 C/A signals (and an attacker) into OUT, with SigMF metadata and a truth log."""
    from .sim.run import simulate_to_file
    from .sim.scenario import load_scenario

    sets = list(sets)
    for key, value in (("signal.format", fmt and f'"{fmt}"'), ("signal.fs_hz", fs_hz), ("signal.if_hz", if_hz),
                       ("time.duration_s", duration_s)):
        if value is not None:
            sets.insert(0, f"{key}={value}")
    try:
        cfg = load_scenario(scenario, sets)
        summary = simulate_to_file(cfg, out_path, progress=sys.stderr.isatty())
    except (ValueError, OSError) as exc:
        _fail(str(exc))
    click.echo(f"wrote {summary.out_path} ({summary.fmt}, {summary.fs_hz / 1e6:g} MSa/s, {summary.duration_s:g} s, "
               f"start {summary.start_utc})")
    click.echo(f"  legitimate PRNs: {' '.join(map(str, summary.legit_prns))}")
    if summary.spoofed_prns:
        a = cfg["attacker"]
        click.echo(f"  spoofed PRNs:    {' '.join(map(str, summary.spoofed_prns))} "
                   f"({a['mode']}, {a['power_advantage_db']:+g} dB, from t = {a['start_s']:g} s)")
    if summary.clipped_fraction > 1e-4:
        click.echo(f"  warning: {100 * summary.clipped_fraction:.3f} % of samples clipped", err=True)


if __name__ == "__main__":
    main()

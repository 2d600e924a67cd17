"""The `semperfi` command."""

import _thread
import sys
import threading
import warnings

import click

from . import __version__
from .receiver import DEFAULTS as RECEIVER_DEFAULTS, RATE_HZ
from .errors import (EXIT_BAD_INPUT, EXIT_INPUT_LOST, EXIT_INPUT_SHORT, EXIT_INTERNAL, EXIT_INTERRUPTED,
                     EXIT_NO_SIGNAL)


def _fail(message: str, code: int = EXIT_BAD_INPUT) -> None:
    """A user's mistake (or what the input turned out to be): one line on stderr and a non-zero exit."""
    click.echo(f"semperfi: error: {message}", err=True)
    sys.exit(code)


def _tune_heap() -> None:
    """Fixed glibc malloc thresholds for a streaming process. Arrays up to 64 MiB come from the heap and are reused
    there: handed back to the system at each free (the mmap default from 128 KiB), every chunk's fresh arrays cost
    the kernel a page fault per 4 KiB (3 million faults, half the run's time, in a 10 MSa/s defended run). Free
    memory at the heap's top beyond 128 MiB still goes back. One arena: worker threads' own arenas would each keep
    their own free memory. Fixed values, not glibc's dynamic threshold (which rises with each big free, and then let
    a long run's peak creep)."""
    import ctypes
    import ctypes.util
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt if name else None
    except (OSError, AttributeError):   # not glibc: nothing to tune
        return
    if mallopt is not None:
        m_trim_threshold, m_mmap_threshold, m_arena_max = -1, -3, -8
        mallopt(m_mmap_threshold, 64 << 20)
        mallopt(m_trim_threshold, 128 << 20)
        mallopt(m_arena_max, 1)


ACQUISITION = RECEIVER_DEFAULTS["acquisition"]   # `acquire` searches as the receiver does unless told otherwise
FORMAT_HELP = ("ibyte | ishort | gr_complex | byte | short (real, with --if) | packed real2 iq2 real2sm iq2sm real4 "
               "iq4 | a SigMF datatype (else from the SigMF sidecar)")


def _input_options(command):
    """--fs, --format, --iq-swap and --if: how the samples of an input are laid out, for every command reading one."""
    for option in reversed((
            click.option("--fs", "fs_hz", type=float, help="sample rate, Hz (else from the SigMF sidecar)"),
            click.option("--format", "fmt", help=FORMAT_HELP),
            click.option("--iq-swap", is_flag=True, help="the front end stores Q before I (spectral inversion)"),
            click.option("--if", "if_hz", type=float, help="intermediate frequency, Hz"))):
        command = option(command)
    return command


def _window_options(command):
    """--skip, --duration and --fs-out: the part of the input to process, and at what rate."""
    for option in reversed((
            click.option("--skip", "skip_s", type=float, default=0.0, show_default=True,
                         help="seconds of input to skip"),
            click.option("--duration", "duration_s", type=float, help="seconds of input to process (default: all)"),
            click.option("--fs-out", "fs_out_hz", type=float,
                         help="processing rate, Hz: decimate the input to it (an integer divisor of --fs; L1 brought "
                              "to 0 Hz)"))):
        command = option(command)
    return command


class _OneLineGroup(click.Group):
    """Whatever escapes a command is one line on stderr and an exit code, never a traceback: a SemperFi error says
    what went wrong (its own code), a bug is an internal error (70)."""

    def invoke(self, ctx):
        from .errors import SemperFiError, describe
        try:
            return super().invoke(ctx)
        except click.exceptions.UsageError as exc:   # a mistyped option or value: one line, not click's usage block
            command = f" {ctx.invoked_subcommand}" if ctx.invoked_subcommand else ""
            click.echo(f"semperfi: error: {exc.format_message()} (semperfi{command} --help says more)", err=True)
            sys.exit(exc.exit_code)
        except (click.exceptions.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except SemperFiError as exc:
            click.echo(f"semperfi: error: {exc}", err=True)
            sys.exit(exc.exit_code)
        except KeyboardInterrupt:   # Ctrl-C where no command keeps partial outputs (run and clean do, and say so)
            click.echo("semperfi: interrupted", err=True)
            sys.exit(EXIT_INTERRUPTED)
        except Exception as exc:
            what = describe(exc)
            click.echo(f"semperfi: internal error: {what['error']} (at {what['where']})", err=True)
            sys.exit(EXIT_INTERNAL)


INTERRUPT_AGAIN_S = 0.05   # a Ctrl-C a finalizer swallowed is raised again this long after (_unraisable)


def _unraisable(unraisable) -> None:
    """sys.unraisablehook: a Ctrl-C that lands in a finalizer (llvmlite's, while numba compiles) is swallowed there
    and printed as a traceback, and the command ran on until killed (the interrupted-run test, once in the full
    suite): it is raised again in the main thread, where the command stops as for any Ctrl-C -- from a timer's
    thread once the hook has returned (raised from within the hook, it is swallowed again). Anything else a
    finalizer raises is one line."""
    if unraisable.exc_type is not None and issubclass(unraisable.exc_type, KeyboardInterrupt):
        threading.Timer(INTERRUPT_AGAIN_S, _thread.interrupt_main).start()
        return
    first = (str(unraisable.exc_value).strip().splitlines() or [""])[0]
    click.echo(f"semperfi: warning: ignored in a finalizer: {unraisable.exc_type.__name__}: {first}", err=True)


@click.group(cls=_OneLineGroup)
@click.version_option(__version__)
def main() -> None:
    """SemperFi: a spoofer-eliminating GPS L1 C/A receiver, and the world it is proven against."""
    sys.unraisablehook = _unraisable
    _tune_heap()
    # numpy's floating-point RuntimeWarnings (all-zero or full-scale samples, a degenerate rate) are no message for a
    # user: what they lead to is reported in words (no signal, clipping, an event); the tests still see them
    warnings.simplefilter("ignore", RuntimeWarning)


@main.command()
@click.argument("scenario", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out_path", required=True, type=click.Path(dir_okay=False), help="IQ file to write")
@click.option("--format", "fmt",
              type=click.Choice(["ibyte", "ishort", "gr_complex", "cfloat", "byte", "short", "float"]),
              help="sample format (byte, short, float: real samples at --if)")
@click.option("--fs", "fs_hz", type=float, help="sample rate, Hz")
@click.option("--if", "if_hz", type=float, help="intermediate frequency, Hz")
@click.option("--duration", "duration_s", type=float, help="seconds to simulate")
@click.option("--set", "sets", multiple=True, metavar="SECTION.KEY=VALUE", help="override a scenario key")
def sim(scenario, out_path, fmt, fs_hz, if_hz, duration_s, sets) -> None:
    """Simulate GPS L1 C/A signals (and an attacker) into OUT, with SigMF metadata and a truth log."""
    from .sim import simulate_to_file
    from .sim import load_scenario

    sets = list(sets)
    for key, value in (("signal.format", fmt and f'"{fmt}"'), ("signal.fs_hz", fs_hz), ("signal.if_hz", if_hz),
                       ("time.duration_s", duration_s)):
        if value is not None:
            sets.insert(0, f"{key}={value}")
    try:
        cfg = load_scenario(scenario, sets)
        summary = simulate_to_file(cfg, out_path, progress=sys.stderr.isatty())
    except (ValueError, OSError) as exc:
        _fail(str(exc), getattr(exc, "exit_code", EXIT_BAD_INPUT))
    click.echo(f"wrote {summary.out_path} ({summary.fmt}, {summary.fs_hz / 1e6:g} MSa/s, {summary.duration_s:g} s, "
               f"start {summary.start_utc})")
    click.echo(f"  legitimate PRNs: {' '.join(map(str, summary.legit_prns))}")
    if summary.spoofed_prns:
        a = cfg["attacker"]
        click.echo(f"  spoofed PRNs:    {' '.join(map(str, summary.spoofed_prns))} "
                   f"({a['mode']}, {a['power_advantage_db']:+g} dB, from t = {a['start_s']:g} s)")
    if summary.clipped_fraction > 1e-4:
        click.echo(f"  warning: {100 * summary.clipped_fraction:.3f} % of samples clipped", err=True)


def _output_folder(path) -> None:
    """Make the folder an output file goes into before any work is done (a missing one must not cost a flight)."""
    import os
    from pathlib import Path
    folder = Path(path).parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _fail(f"cannot write {path}: {exc.strerror or exc}")
    if not os.access(folder, os.W_OK):
        _fail(f"cannot write {path}: {folder} is not writable")


def _parse_prns(text: str) -> list[int]:
    prns: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        try:
            first, last = int(lo), int(hi or lo)
        except ValueError:
            _fail(f"--prn wants a list like 1-32 or 3,7,19; got '{text}'")
        if not 1 <= first <= last <= 32:   # checked before the range is made: 1-99999999 is no list to build
            _fail(f"--prn wants PRNs between 1 and 32; got '{text}'")
        prns.extend(range(first, last + 1))
    return prns


@main.command()
@click.argument("file", type=click.Path(dir_okay=False))
@_input_options
@click.option("--prn", "prn_text", default="1-32", show_default=True, help="PRNs to search")
@click.option("--skip", "--start", "start_s", type=float, default=0.0, show_default=True,
              help="seconds of input to skip (--start: the same)")
@click.option("--coherent-ms", type=click.IntRange(1, 20), default=ACQUISITION["coherent_ms"], show_default=True)
@click.option("--noncoherent", type=click.IntRange(1, 1000), default=ACQUISITION["noncoherent"], show_default=True)
@click.option("--doppler-max", "doppler_max_hz", type=click.FloatRange(0.0, 50000.0),
              default=ACQUISITION["doppler_max_hz"],
              show_default=True, help="Hz: a receiver on the ground sees under 5 kHz, one at 500 m/s under 7 kHz")
@click.option("--doppler-step", "doppler_step_hz", type=click.FloatRange(0.0, 5000.0),
              default=ACQUISITION["doppler_step_hz"],
              help="Hz; default 2/3 of 1/coherent")
@click.option("--pfa", type=click.FloatRange(0.0, 0.5, min_open=True), default=ACQUISITION["pfa"], show_default=True,
              help="false-alarm probability per PRN search")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), help="write the CAFs of acquired PRNs as PNG")
def acquire(file, fs_hz, fmt, iq_swap, if_hz, prn_text, start_s, coherent_ms, noncoherent, doppler_max_hz,
            doppler_step_hz, pfa, plot_path) -> None:
    """Search FILE for every PRN: one line per PRN with code phase, Doppler, C/N0, peak ratio and peak count."""
    from .iq import open_source
    from .receiver import DopplerGrid, acquire as run_acquisition

    prns = _parse_prns(prn_text)
    if plot_path:
        _output_folder(plot_path)
    if 0.0 < doppler_step_hz < 1.0:
        _fail(f"--doppler-step wants 0 (the default grid) or 1 Hz or more; got {doppler_step_hz:g}")
    try:
        source = open_source(file, _sample_format(fmt, iq_swap), fs_hz, if_hz, skip_s=start_s)
        try:
            samples = source.take(int(round(source.fs_hz * 1e-3)) * coherent_ms * noncoherent)
        finally:
            source.close()
        grid = DopplerGrid.for_coherent(coherent_ms, doppler_max_hz, doppler_step_hz)
        cafs = run_acquisition(samples, source.fs_hz, prns, grid, source.if_hz,
                               coherent_ms, noncoherent, pfa, excise=True,
                               tail_threshold=True)
    except ValueError as exc:
        _fail(str(exc))
    interference = next(iter(cafs.values())).interference
    if interference.present:
        click.echo(f"warning: {interference.describe()}", err=True)
    click.echo(f"{'PRN':>3}  {'code phase':>11}  {'Doppler':>9}  {'C/N0':>6}  {'ratio':>6}  {'2nd':>5}  peaks")
    found = 0
    for prn, caf in cafs.items():
        if caf.best is None:
            continue
        found += 1
        b = caf.best
        click.echo(f"{prn:>3}  {b.code_phase_chips:>7.3f} ch  {b.doppler_hz:>6.0f} Hz  {b.cn0_dbhz:>6.1f}  "
                   f"{caf.peak_ratio:>6.1f}  {caf.second_peak_ratio:>5.2f}  {len(caf.peaks)}")
    if plot_path and found:
        from .receiver import plot_cafs
        plot_cafs([c for c in cafs.values() if c.best], plot_path)
    if not found and interference.present:
        _fail(f"no satellite acquired in {file} under its {interference.describe()}", EXIT_NO_SIGNAL)
    if not found:
        _fail(f"no satellite acquired in {file}: check --fs ({source.fs_hz:g} Hz), --format ({source.fmt.name}) "
              f"and --if ({source.if_hz:g} Hz), and that the file holds GPS L1 signals", EXIT_NO_SIGNAL)


@main.command()
@click.argument("file", type=click.Path(dir_okay=False))
@_input_options
@click.option("--nav", "nav_path", type=click.Path(dir_okay=False), help="RINEX navigation file (assisted mode)")
@click.option("--out", "out_dir", default="out/run", show_default=True, type=click.Path(file_okay=False))
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="receiver TOML configuration")
@click.option("--defense", type=click.Choice(["off", "detect", "full"]),
              help="SemperFi's defence (default full; off = the conventional receiver)")
@click.option("--adversarial", help="which peak is the attacker's: auto | stronger | later | prn:LIST")
@click.option("--set", "sets", multiple=True, metavar="SECTION.KEY=VALUE", help="override a configuration key")
@_window_options
@click.option("--imu", "imu_path", type=click.Path(dir_okay=False),
              help="INS-only track t_s,north_m,east_m,down_m (t_s from FILE's first sample) with a maneuver in it: "
                   "the Adversarial Peak Identifier decides which peaks are the attacker's")
@click.option("--link", "link_addr", metavar="HOST:PORT",
              help="the flight side's authenticated link (semperfi companion): on an alarm it flies a maneuver and "
                   "sends the IMU track back")
@click.option("--link-key", "link_key_path", type=click.Path(dir_okay=False),
              help="file holding the link's pre-shared key")
@click.option("--mavlink-gps", "mavlink_gps_url", metavar="URL",
              help="be an autopilot's GPS: every fix as MAVLink GPS_INPUT at 10 Hz (ArduPilot GPS1_TYPE 14) to "
                   "udpout:HOST:PORT, tcp:HOST:PORT or a serial device; no fix while spoofing is suspected")
@click.option("--nmea-out", "nmea_out_url", metavar="URL",
              help="every fix as NMEA GGA+RMC at 10 Hz to tcp:HOST:PORT, udpout:HOST:PORT or a serial device "
                   "(marked invalid while spoofing is suspected)")
@click.option("--fix-rate", "fix_rate_hz", type=click.FloatRange(1.0, 100.0), default=RATE_HZ, show_default=True,
              help="messages a second to --mavlink-gps and --nmea-out (an autopilot simulated N times faster than "
                   "real time wants N times more)")
def run(file, fs_hz, fmt, iq_swap, if_hz, nav_path, out_dir, config_path, defense, adversarial, sets, skip_s,
        duration_s, fs_out_hz, imu_path, link_addr, link_key_path, mavlink_gps_url, nmea_out_url,
        fix_rate_hz) -> None:
    """Receive FILE (a recording, - for standard input, or rtl_tcp://HOST:PORT): acquisition, tracking, navigation,
    PVT; fixes.csv, NMEA, GPX, GeoJSON, RINEX observations, events.jsonl in --out."""
    import functools

    from .defense import load_config
    from .defense import DefendedReceiver
    from .defense import read_imu_csv
    from .receiver import run_file

    sets = (list(sets) + [f'defense.mode="{defense}"'] * bool(defense)
            + [f'defense.adversarial="{adversarial}"'] * bool(adversarial))
    try:
        cfg = load_config(config_path, sets)
        imu = read_imu_csv(imu_path).shifted(-skip_s) if imu_path else None   # its t_s counts from FILE's start
        link = _flight_link(link_addr, link_key_path)
        streams = _fix_streams(mavlink_gps_url, nmea_out_url, fix_rate_hz, out_dir)
        try:
            summary = run_file(file, _sample_format(fmt, iq_swap), fs_hz, if_hz, cfg, out_dir, nav_path,
                               live=sys.stderr.isatty(),
                               receiver_factory=functools.partial(DefendedReceiver, imu_track=imu, flight_link=link),
                               skip_s=skip_s, duration_s=duration_s, fs_out_hz=fs_out_hz,
                               fix_streams=[s for s, _ in streams])
        finally:
            if link is not None:
                link.close()
            for stream, sink in streams:
                stream.close()
                sink.close()
    except (ValueError, OSError) as exc:
        _fail(str(exc), getattr(exc, "exit_code", EXIT_BAD_INPUT))
    _print_run_summary(summary)
    for stream, sink in streams:
        click.echo(f"  {type(sink).__name__}: {stream.sent} messages sent, {stream.failed} failed")
    _fail_after(summary)


def _fix_streams(mavlink_gps_url, nmea_out_url, rate_hz: float, out_dir: str) -> list:
    """The fix streams asked for: (FixStream, its sink), each opened now so a wrong address fails before the run.
    Every GPS_INPUT sent is also logged in out_dir/gps_input.csv."""
    from .receiver import FixStream
    from .receiver import MavlinkGpsOut
    from .receiver import NmeaOut
    from pathlib import Path
    sinks = []
    if mavlink_gps_url:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        sinks.append(MavlinkGpsOut(mavlink_gps_url, log_path=Path(out_dir) / "gps_input.csv"))
    if nmea_out_url:
        sinks.append(NmeaOut(nmea_out_url))
    return [(FixStream(sink.send, rate_hz), sink) for sink in sinks]


@main.command()
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out_path", required=True, type=click.Path(dir_okay=False), help="cleaned IQ file")
@_input_options
@click.option("--adversarial", help="which peak is the attacker's: auto | stronger | later | prn:LIST")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="TOML configuration")
@click.option("--set", "sets", multiple=True, metavar="SECTION.KEY=VALUE", help="override a configuration key")
@_window_options
def clean(file, out_path, fs_hz, fmt, iq_swap, if_hz, adversarial, config_path, sets, skip_s, duration_s,
          fs_out_hz) -> None:
    """Plug-in filter: write FILE (or - for standard input, rtl_tcp://HOST:PORT) with the spoofer's signals cancelled
    to OUT (same format and rate; complex integers after --fs-out or from packed input), for any receiver; events go
    to OUT's stem + .events.jsonl."""
    from .defense import clean_file
    from .defense import load_config

    sets = ['defense.mode="full"'] + list(sets) + [f'defense.adversarial="{adversarial}"'] * bool(adversarial)
    try:
        cfg = load_config(config_path, sets)
        s = clean_file(file, out_path, _sample_format(fmt, iq_swap), fs_hz, if_hz, cfg, progress=sys.stderr.isatty(),
                       skip_s=skip_s, duration_s=duration_s, fs_out_hz=fs_out_hz)
    except (ValueError, OSError) as exc:
        _fail(str(exc), getattr(exc, "exit_code", EXIT_BAD_INPUT))
    click.echo(f"cleaned {s.duration_s:.1f} s in {s.wall_s:.1f} s into {s.out_path}")
    click.echo(f"  alarms on PRNs {' '.join(map(str, s.alarms)) or 'none'}; "
               f"cancelled {' '.join(map(str, s.cancelled)) or 'none'}; "
               f"verified clean {' '.join(map(str, s.verified)) or 'none'}")
    for prn, stages in sorted(s.attenuation_db.items()):
        last = [st["attenuation_db"][-1] for st in stages if st["attenuation_db"]]
        click.echo(f"  PRN {prn:>2}: attenuation {', '.join(map(str, last)) or 'not yet measured'} dB (per SIC stage)")
    if s.gave_up:
        click.echo(f"  gave up on: {s.gave_up}", err=True)
    if s.removed:
        click.echo(f"  taken out whole (the output leaves them out): PRNs {' '.join(map(str, s.removed))}", err=True)
    if s.remnants:
        click.echo(f"  spoofers' remnants taken out (the satellites kept): PRNs {' '.join(map(str, s.remnants))}",
                   err=True)
    if s.interference:
        click.echo(f"  warning: {s.interference} (left in the output)", err=True)
    if not s.satellites and not (s.internal_error or s.input_error or s.interrupted):
        what = f"under its {s.interference}" if s.interference else \
            "check --fs, --format and --if, and that it holds GPS L1 signals"
        _fail(f"no satellite signal found in {file} ({s.out_path} is written, uncleaned): {what}", EXIT_NO_SIGNAL)
    _fail_after(s)


def _fail_after(summary) -> None:
    """A run or clean that stopped part-way or ran short: one line, and the exit code that says why (outputs are
    kept)."""
    if summary.internal_error:
        click.echo(f"semperfi: internal error after {summary.duration_s:.1f} s of input (outputs kept, the event in "
                   f"the event log): {summary.internal_error}", err=True)
        sys.exit(EXIT_INTERNAL)
    if summary.input_error:
        _fail(f"input failed after {summary.duration_s:.1f} s (outputs kept): {summary.input_error}", EXIT_INPUT_LOST)
    if summary.interrupted:
        click.echo(f"semperfi: interrupted after {summary.duration_s:.1f} s of input (outputs kept)", err=True)
        sys.exit(EXIT_INTERRUPTED)
    short = []
    if summary.missing_s > 0:
        short.append(f"the input ended {summary.missing_s:.3f} s before the --duration asked for")
    if summary.truncated_bytes:
        short.append(f"the input ends mid-sample ({summary.truncated_bytes} trailing bytes ignored)")
    if short:
        click.echo(f"semperfi: warning: {'; '.join(short)}: all of it was processed (outputs complete)", err=True)
        sys.exit(EXIT_INPUT_SHORT)


def _read_key(path) -> bytes:
    """The link's pre-shared key: a file of at least 16 bytes (hex or raw), readable by its owner only."""
    import os
    import stat
    if path is None:
        raise ValueError("the link needs --link-key (a file holding the pre-shared key)")
    if os.stat(path).st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ValueError(f"link key {path} is readable by others: chmod 600 it")
    raw = open(path, "rb").read(4096).strip()
    try:
        key = bytes.fromhex(raw.decode("ascii"))
    except ValueError:
        key = raw
    if len(key) < 16:
        raise ValueError(f"link key {path} is shorter than 16 bytes")
    return key


def _flight_link(addr, key_path):
    """The receiver's end of the link to the flight side, or None."""
    if not addr:
        return None
    from .flight import LinkPeer
    host, _, port = addr.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--link wants HOST:PORT, got {addr!r}")
    return LinkPeer.connect(host, int(port), _read_key(key_path))   # LinkError: a BadInput, told in one line


def _sample_format(fmt, iq_swap: bool):
    """--format, with I and Q exchanged when --iq-swap says so (raises ValueError on a bad name)."""
    if not iq_swap:
        return fmt
    from .iq import with_iq_swap
    if fmt is None:
        raise ValueError("--iq-swap needs --format (the swap is part of how the samples are laid out)")
    return with_iq_swap(fmt)


def _print_run_summary(summary) -> None:
    s = summary.stats
    click.echo(f"processed {summary.duration_s:.1f} s of signal in {summary.wall_s:.1f} s "
               f"({summary.duration_s / max(summary.wall_s, 1e-9):.2f}x real time)")
    click.echo(f"  tracked PRNs: {' '.join(map(str, sorted(s.confirmed)))}; subframes decoded {s.subframes}, "
               f"parity errors {s.parity_errors}")
    if summary.last_fix is None:
        click.echo("  no fix: fewer than four satellites with ephemeris and time (a fix needs ~30 s of signal, or "
                   "--nav RINEX)")
    else:
        f = summary.last_fix
        click.echo(f"  {s.n_fixes} fixes, first at t = {s.first_fix_t_rx_s:.1f} s; last: {f.lat_deg:.7f} "
                   f"{f.lon_deg:.7f} {f.height_m:.1f} m, {f.n_sats} satellites, PDOP {f.pdop:.1f}, {f.state}, "
                   f"time {f.time_state}")
    if summary.defence:
        click.echo(f"  defence: {summary.defence}")
    click.echo(f"  outputs: {summary.out_dir}")


@main.command()
@click.option("--port", type=click.IntRange(1, 65535), default=14550, show_default=True, help="UDP port to listen on")
@click.option("--seed", type=int, default=0, show_default=True, help="seed of the IMU errors and the gusts")
@click.option("--altitude", "altitude_m", type=click.FloatRange(1.0, 1000.0), default=50.0, show_default=True)
@click.option("--heading", "heading_deg", type=click.FloatRange(-360.0, 360.0), default=0.0, show_default=True)
@click.option("--time-scale", type=click.FloatRange(0.01, 100.0), default=1.0, show_default=True,
              help="vehicle seconds per wall second")
@click.option("--on-ground", is_flag=True, help="disarmed on the ground (it never takes off), not airborne")
def vehicle(port, seed, altitude_m, heading_deg, time_scale, on_ground) -> None:
    """A simulated multicopter behind a MAVLink endpoint (UDP 127.0.0.1:PORT), as ArduCopter in GUIDED obeys it:
    it streams only what SET_MESSAGE_INTERVAL asks for, and turns to face its travel unless given a heading."""
    import math
    import threading

    from .sim import MavlinkVehicle

    try:
        v = MavlinkVehicle(port, seed=seed, altitude_m=altitude_m, heading_rad=math.radians(heading_deg),
                           time_scale=time_scale, airborne=not on_ground)
    except (ValueError, OSError) as exc:
        _fail(f"cannot start the vehicle on port {port}: {exc}")
    where = "disarmed on the ground in STABILIZE" if on_ground else f"airborne at {altitude_m:g} m in LOITER"
    click.echo(f"vehicle on udp 127.0.0.1:{port}, {where}; Ctrl-C stops it")
    try:
        v.run(threading.Event())
    except KeyboardInterrupt:
        click.echo(f"stopped at t = {v.t_s:.1f} s; {v.setpoints} setpoints obeyed, {v.rejected} inputs rejected")


@main.command()
@click.option("--vehicle", "url", default="udpout:127.0.0.1:14550", show_default=True,
              help="the vehicle's MAVLink address (pymavlink connection string)")
@click.option("-o", "--out", "out_path", type=click.Path(dir_okay=False), help="write the IMU track here (CSV)")
@click.option("--timeout", "timeout_s", type=click.FloatRange(1.0, 600.0), default=10.0, show_default=True,
              help="the longest wait for an answer, and the longest silence of a stream")
def fly(url, out_path, timeout_s) -> None:
    """Fly a pseudorandom maneuver (from the OS's cryptographic source, drawn for the vehicle's height and track)
    over MAVLink in GUIDED, and dead-reckon it from the vehicle's IMU; the track (t_s in vehicle boot seconds) goes
    to --out. The vehicle must be armed and in the air; it is given back to its mode afterwards."""
    import math

    from .flight import ins_error_bound_m, write_track_csv
    from .flight import ManeuverLimits, draw
    from .flight import Pilot, check_vehicle_url

    try:
        check_vehicle_url(url)
    except ValueError as exc:
        _fail(str(exc))
    if out_path:
        _output_folder(out_path)
    try:
        pilot = Pilot(url, timeout_s=timeout_s)
        try:
            status = pilot.prepare()
            maneuver = draw(ManeuverLimits(), track_heading_rad=status.track_heading_rad,
                            altitude_m=status.height_above_home_m)
            click.echo(f"maneuver at {status.height_above_home_m:.1f} m above home: {len(maneuver.legs)} legs, "
                       f"{maneuver.duration_s:.1f} s, {maneuver.path_length_m:.1f} m flown, ends "
                       f"{maneuver.end_distance_m:.1f} m from its start")
            flown = pilot.fly(maneuver)
        finally:
            pilot.close()
    except (ValueError, RuntimeError, OSError) as exc:   # PilotError is a ValueError (errors.BadInput)
        _fail(f"flight over {url} failed: {exc}")
    end = flown.ins.pos_ned_m[-1] - flown.ins.pos_ned_m[0]
    t_end = flown.ins.t_s[-1]
    click.echo(f"flown from vehicle time {flown.start_time_boot_s:.2f} s for {t_end:.1f} s; the IMU puts the end "
               f"{math.hypot(*end[:2]):.1f} m from the start (within {float(ins_error_bound_m(t_end)):.1f} m)")
    if out_path:
        write_track_csv(out_path, flown.ins.t_s + flown.start_time_boot_s, flown.ins.pos_ned_m)
        click.echo(f"IMU track: {out_path}")


@main.command()
@click.option("--port", type=click.IntRange(1, 65535), required=True, help="TCP port of the link (127.0.0.1)")
@click.option("--link-key", "link_key_path", required=True, type=click.Path(dir_okay=False))
@click.option("--vehicle", "url", default="udpout:127.0.0.1:14550", show_default=True)
@click.option("--maneuvers", type=click.IntRange(1, 100), default=1, show_default=True)
@click.option("--test-seed", type=int, hidden=True,
              help="TESTS ONLY: seed the maneuver draw, which makes it predictable to an attacker; never in flight")
def companion(port, link_key_path, url, maneuvers, test_seed) -> None:
    """The flight side: serve the receiver's link, answer alarms with maneuvers flown over MAVLink (JSON lines)."""
    import json
    import random

    from .flight import serve
    from .flight import check_vehicle_url

    def report(event: dict) -> None:
        click.echo(json.dumps(event, separators=(",", ":")))
        sys.stdout.flush()

    try:
        check_vehicle_url(url)
        serve(port, _read_key(link_key_path), url, report, max_maneuvers=maneuvers,
              rng=random.Random(test_seed) if test_seed is not None else None)
    except (ValueError, OSError) as exc:
        _fail(str(exc))


@main.command()
@click.argument("scenario", required=False, type=click.Path(dir_okay=False))
@click.option("--mavlink-port", type=click.IntRange(1, 65535), default=14550, show_default=True)
@click.option("--truth", "truth_path", required=True, type=click.Path(dir_okay=False), help="vehicle truth CSV")
@click.option("--altitude", "altitude_m", type=click.FloatRange(1.0, 1000.0), default=50.0, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--tee", "tee_path", type=click.Path(dir_okay=False), help="also keep the samples in this recording")
@click.option("--set", "sets", multiple=True, metavar="SECTION.KEY=VALUE", help="override a scenario key")
def world(scenario, mavlink_port, truth_path, altitude_m, seed, tee_path, sets) -> None:
    """The closed loop's world: the vehicle behind MAVLink, and its GPS signals (and the attacker's) as IQ on stdout."""
    from .sim import load_scenario
    from .sim import run_world

    try:
        cfg = load_scenario(scenario, list(sets))
        run_world(cfg, sys.stdout.buffer, mavlink_port, truth_path, seed=seed, altitude_m=altitude_m,
                  tee_path=tee_path)
    except (ValueError, OSError) as exc:
        _fail(str(exc), getattr(exc, "exit_code", EXIT_BAD_INPUT))


@main.command()
@click.option("--out", "out_dir", default="out/demo", show_default=True, type=click.Path(file_okay=False))
@click.option("--duration", "duration_s", type=float, default=95.0, show_default=True)
@click.option("--set", "sets", multiple=True, metavar="SECTION.KEY=VALUE", help="override a scenario key")
@click.option("--autopilot", "autopilot_path", type=click.Path(dir_okay=False, exists=True),
              help="fly the closed loop on this ArduCopter SITL executable (copter.parm beside it is loaded): "
                   "SemperFi is its only GPS (--duration does not apply: the loop ends after the recovery)")
@click.option("--speedup", type=click.FloatRange(0.1, 10.0), default=1.0, show_default=True,
              help="with --autopilot: SITL's speed-up over real time (the world slows it down no further)")
@click.option("--instance", type=click.IntRange(0, 50), default=6, show_default=True,
              help="with --autopilot: SITL's -I (its TCP ports are 5760 + 10 x instance, +2, +3)")
def demo(out_dir, duration_s, sets, autopilot_path, speedup, instance) -> None:
    """The main job on its built-in scenario: a spoofing attack, a conventional receiver it fools, and SemperFi.
    With --autopilot: the same attack on ArduCopter SITL in flight, SemperFi as its GPS."""
    try:
        if autopilot_path:
            from .eval import run_autopilot_loop, report
            result = run_autopilot_loop(out_dir, autopilot_path, speedup, instance, list(sets), log=click.echo)
            for line in report(result):
                click.echo(line)
            if result.errors:
                _fail(f"the loop did not finish: {result.errors[0]}", EXIT_INTERNAL)
            return
        from .eval import run_demo
        for line in run_demo(out_dir, duration_s, list(sets), progress=sys.stderr.isatty()):
            click.echo(line)
    except (ValueError, OSError) as exc:
        _fail(str(exc), getattr(exc, "exit_code", EXIT_BAD_INPUT))


@main.command(name="eval")
@click.option("--suite", "suite", type=click.Choice(["quick", "paper", "full", "tiny"]), default=None,
              help="the paper's evaluation: each figure and table run again, ours beside the paper's (quick: under "
                   "10 minutes; tiny: what CI runs)")
@click.option("--generator", type=click.Choice(["auto", "ours", "gps-sdr-sim", "both"]), default="auto",
              show_default=True, help="with --suite: what renders the recordings (auto: ours, and GPS-SDR-SIM when "
                                      "it is found)")
@click.option("--sweep", "spec_path", default=None, type=click.Path(dir_okay=False),
              help="the sweep's spec (TOML: [sweep] and [space], see semperfi.eval.sweep)")
@click.option("--nav", "nav_path", default=None, type=click.Path(dir_okay=False),
              help="RINEX 2 GPS navigation file the scenes are rendered from (their day is its day); a sweep needs "
                   "it, a suite on our simulator alone synthesizes a constellation without it")
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False),
              help="[default: out/sweep, or out/suite-NAME]")
@click.option("--ray-address", default=None, help="a Ray cluster's address (default: Ray on this machine)")
@click.option("--pool", is_flag=True, help="a local process pool even when Ray is installed")
@click.option("--workers", type=click.IntRange(1, 256), default=2, show_default=True,
              help="with the process pool: how many cells at once")
@click.option("--only", "only_id", default=None, metavar="CELL_ID", help="run this one cell here (a row's repro)")
def evaluate(suite, generator, spec_path, nav_path, out_dir, ray_address, pool, workers, only_id) -> None:
    """The paper's evaluation (--suite), or a sweep over a scenario space (--sweep: every cell a scene received by
    SemperFi, one row of OUT/results.csv and .parquet each as it finishes; a rerun skips the cells already there).
    Either ends with OUT/report.html."""
    try:
        if (suite is None) == (spec_path is None):
            raise click.UsageError("give --suite NAME or --sweep SPEC.toml (one of them)")
        if suite:
            _evaluate_suite(suite, generator, nav_path, out_dir or f"out/suite-{suite}")
        else:
            if nav_path is None:
                raise click.UsageError("a sweep needs --nav (the RINEX file its scenes are rendered from)")
            _evaluate_sweep(spec_path, nav_path, out_dir or "out/sweep", ray_address, pool, workers, only_id)
    except (ValueError, OSError) as exc:   # SweepError, SuiteError too (errors.BadInput)
        _fail(str(exc), getattr(exc, "exit_code", EXIT_BAD_INPUT))


def _evaluate_suite(suite: str, generator: str, nav_path: str | None, out_dir: str) -> None:
    from .eval import run_suite

    def told(gen, fig) -> None:
        click.echo(f"[{gen}] {fig.title}: " + (f"FAILED {fig.error}" if fig.error else
                                                  "; ".join(f"{what}: {ours} (paper {paper})"
                                                            for what, paper, ours in fig.rows[:3])))
        sys.stdout.flush()
    click.echo(run_suite(suite, out_dir, nav_path, generator, told))


def _evaluate_sweep(spec_path, nav_path, out_dir, ray_address, pool, workers, only_id) -> None:
    import json
    import time

    from .eval import load_spec, ray_available, read_results, run_only, run_sweep
    from .eval import render_report
    spec = load_spec(spec_path)
    if only_id:
        click.echo(json.dumps(run_only(spec, nav_path, out_dir, only_id)))
        return
    if not pool and not ray_available():
        click.echo("semperfi: Ray is not installed (pip install semperfi[sweep]): the cells run in a local "
                   "process pool; Ray would spread them over a cluster", err=True)

    started, ran, failed = time.monotonic(), 0, 0

    def told(row, done, total):
        nonlocal ran, failed
        ran, failed = ran + 1, failed + bool(row.get("error"))
        rate_s = (time.monotonic() - started) / ran    # this run's seconds per cell
        state = "FAILED " + str(row.get("error")) if row.get("error") else (
            f"availability {row.get('availability')}, last 10 s {row.get('last_mean_m')} m")
        click.echo(f"[{done}/{total}, {failed} failed, ~{rate_s * (total - done) / 60:.0f} min left] "
                   f"{row['cell_id']} {row['kind']} {row['place']} {row['date']} {row['offset_m']:g} m "
                   f"{row['advantage_db']:+g} dB: {state}")
        sys.stdout.flush()
    summary = run_sweep(spec, nav_path, out_dir, "pool" if pool else "auto", workers, ray_address, told)
    report = render_report(read_results(f"{out_dir}/results.csv"), out_dir)
    click.echo(f"{summary.cells} cells: {summary.skipped} already done, {summary.ran} run on {summary.backend}, "
               f"{summary.failed} failed; {report}")


@main.command()
@click.argument("results", type=click.Path(dir_okay=False, exists=True))
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False),
              help="where report.html goes (default: beside RESULTS)")
def report(results, out_dir) -> None:
    """Render a report without running anything: a sweep's from its results table (CSV or Parquet), a suite's from
    its figures.json (beside it)."""
    from pathlib import Path

    from .eval import render_suite_report
    from .eval import read_results
    from .eval import render_report
    try:
        if Path(results).suffix == ".json":
            click.echo(render_suite_report(results))
            return
        click.echo(render_report(read_results(results), out_dir or Path(results).parent))
    except (ValueError, OSError) as exc:   # SweepError too (errors.BadInput)
        _fail(str(exc))


if __name__ == "__main__":
    main()

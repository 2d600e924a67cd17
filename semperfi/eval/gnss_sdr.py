"""Run GNSS-SDR (an independent receiver) on an IQ file and read back its position fixes.

GNSS-SDR 0.0.17 is configured for GPS L1 C/A only: file source -> (IF removal) -> PCPS acquisition -> DLL/PLL
tracking -> NAV decoding -> observables -> RTKLIB single-point PVT. The fixes are read from the NMEA file it writes
($GxGGA sentences), which needs no GNSS-SDR-specific binary parser.

Standard library and numpy only, so this module works wherever the simulator does.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pymap3d
from pynmeagps import VALCKSUM, NMEAParseError, NMEAReader, NMEATypeError

GNSS_SDR_EXE = "gnss-sdr"
CONFIG_NAME = "gnss-sdr_semperfi.conf"
LOG_NAME = "gnss-sdr.log"              # GNSS-SDR's stdout + stderr
OUTPUT_STEM = "gnss_sdr_pvt"           # GNSS-SDR names its KML/GPX/GeoJSON '<PVT.dump_filename>_YYMMDD_HHMMSS.*'
NMEA_NAME = OUTPUT_STEM + ".nmea"      # PVT.nmea_dump_filename; found again by globbing *.nmea
SAMPLES_LINK = "samples"               # the samples, linked into the run's directory under a short name
NOT_STARTED = "Unable to connect flowgraph"   # what GNSS-SDR says when it cannot open its samples, then exits 0
COMPLEX_ITEM_TYPES = ("ishort", "ibyte", "gr_complex")
REAL_ITEM_TYPES = ("short",)   # real samples at an IF: the input filter mixes them to complex baseband
ITEM_TYPES = (*COMPLEX_ITEM_TYPES, *REAL_ITEM_TYPES)
_DATA_TYPE_ADAPTER = {"ishort": "Ishort_To_Complex", "ibyte": "Ibyte_To_Complex", "gr_complex": "Pass_Through",
                      "short": "Pass_Through"}
IONO_MODELS = ("OFF", "Broadcast", "SBAS", "Iono-Free-LC", "Estimate_STEC", "IONEX")
TROP_MODELS = ("OFF", "Saastamoinen", "SBAS", "Estimate_ZTD", "Estimate_ZTD_Grad")

@dataclass(frozen=True)
class Fix:
    """One GNSS-SDR position fix, from one $GxGGA sentence."""
    t_utc: str          # 'hh:mm:ss.sss' as GNSS-SDR wrote it (UTC time of day; NMEA GGA carries no date)
    t_sod_s: float      # the same time as seconds of the UTC day
    lat_deg: float
    lon_deg: float
    height_m: float     # above the WGS 84 ellipsoid: GGA altitude + geoid separation
    n_sats: int         # satellites used
    hdop: float         # nan when the field is empty
    date_utc: str = ""  # 'YYYY-MM-DD' from the $GxRMC sentence of the same epoch, '' when there is none


# ----------------------------------------------------------------------------------------------------- config

def _conf_value(value: str, what: str) -> str:
    """A value GNSS-SDR's INI reader keeps intact: ';' and '#' start comments there, and a newline ends the line."""
    if any(c in value for c in ";#\r\n") or value != value.strip() or not value:
        raise ValueError(f"{what} {value!r} cannot be written into a GNSS-SDR configuration "
                         "(empty, surrounding spaces, or contains ';', '#' or a line break)")
    return value


def _integer_hz(value: float, what: str) -> int:
    """GNSS-SDR.internal_fs_sps is an integer, so sample rates must be whole numbers of Hz."""
    value = float(value)
    if not math.isfinite(value) or value <= 0 or abs(value - round(value)) > 1e-6:
        raise ValueError(f"{what} must be a positive whole number of Hz for GNSS-SDR, got {value!r}")
    return int(round(value))


def _fmt_float(value: float) -> str:
    """A float as GNSS-SDR parses it: plain decimal, no exponent."""
    text = f"{value:.6f}".rstrip("0").rstrip(".")
    return text if text not in ("", "-0") else "0"


def gnss_sdr_config(data_file: str | os.PathLike, fs_hz: float, item_type: str, if_hz: float = 0.0,
                    channels: int = 12, out_dir: str | os.PathLike = ".", trop_model: str = "Saastamoinen",
                    iono_model: str = "Broadcast", output_rate_ms: int = 100, doppler_max_hz: int = 10000,
                    elevation_mask_deg: float = 5.0, rinex: bool = False, max_dwells: int = 1) -> str:
    """A complete GNSS-SDR 0.0.17 configuration for GPS L1 C/A from `data_file` (a path made absolute; a bare file
    name stays as written, in the directory GNSS-SDR runs in, as out_dir).

    `item_type` is GNSS-SDR's name of the sample format ('ishort' = interleaved int16 I/Q, 'ibyte' = int8 I/Q,
    'gr_complex' = complex64, 'short' = real int16 at an IF). `if_hz` is where L1 sits in the band (the signal is
    multiplied by exp(-j 2 pi if_hz t) and low-passed before acquisition, which takes a real signal's mirror
    image away too); 0 uses a pass-through filter (complex samples only). NMEA, GPX, KML and GeoJSON go to
    `out_dir` (as written: relative to where GNSS-SDR runs); RINEX 3 observations and navigation too when `rinex`;
    XML ephemeris dumps and RTCM are off. `max_dwells`: the acquisition's dwells on a PRN and Doppler before it
    gives up (1 ms each; 2 brings 36-40 dB-Hz satellites in, which one dwell at pfa 0.01 mostly misses).
    """
    if not 1 <= int(max_dwells) <= 20:
        raise ValueError(f"max_dwells must be 1-20, got {max_dwells!r}")
    if item_type not in ITEM_TYPES:
        raise ValueError(f"item_type must be one of {', '.join(ITEM_TYPES)}, got {item_type!r}")
    if trop_model not in TROP_MODELS:
        raise ValueError(f"trop_model must be one of {', '.join(TROP_MODELS)}, got {trop_model!r}")
    if iono_model not in IONO_MODELS:
        raise ValueError(f"iono_model must be one of {', '.join(IONO_MODELS)}, got {iono_model!r}")
    fs = _integer_hz(fs_hz, "fs_hz")
    if_hz = float(if_hz)
    if not math.isfinite(if_hz) or abs(if_hz) >= fs / 2:
        raise ValueError(f"if_hz must be finite and inside +-fs/2 (+-{fs / 2:g} Hz), got {if_hz!r}")
    real = item_type in REAL_ITEM_TYPES
    if real and if_hz == 0.0:
        raise ValueError(f"real samples ({item_type!r}) need an IF: if_hz is 0")
    channels = int(channels)
    if not 1 <= channels <= 64:
        raise ValueError(f"channels must be 1..64, got {channels}")
    output_rate_ms = int(output_rate_ms)
    if output_rate_ms <= 0 or output_rate_ms % 20:
        # observables come every GNSS-SDR.observable_interval_ms (20 ms); the PVT rate must be a multiple of it
        raise ValueError(f"output_rate_ms must be a positive multiple of 20, got {output_rate_ms}")
    doppler_max_hz = int(doppler_max_hz)
    if not 1000 <= doppler_max_hz <= 50000:
        raise ValueError(f"doppler_max_hz must be 1000..50000, got {doppler_max_hz}")
    data_file = Path(data_file)
    data = _conf_value(str(data_file if data_file.name == str(data_file) else data_file.resolve()), "data file path")
    out = _conf_value(str(out_dir), "output directory")

    if if_hz == 0.0:
        input_filter = [
            "InputFilter.implementation=Pass_Through",
            "InputFilter.item_type=gr_complex",
            "InputFilter.input_item_type=gr_complex",
            "InputFilter.output_item_type=gr_complex",
        ]
    else:
        # gr::filter::freq_xlating_fir_filter: mixes by exp(-j 2 pi IF t), then a Parks-McClellan low-pass
        # (normalised to Nyquist) that keeps the C/A main lobe (+-1.023 MHz) at any fs >= 2.5 MHz.
        pass_edge = min(0.9, max(0.5, 2.0 * 1.2e6 / fs))
        input_filter = [
            "InputFilter.implementation=Freq_Xlating_Fir_Filter",
            f"InputFilter.input_item_type={item_type if real else 'gr_complex'}",
            "InputFilter.output_item_type=gr_complex",
            "InputFilter.taps_item_type=float",
            f"InputFilter.sampling_frequency={fs}",
            f"InputFilter.IF={_fmt_float(if_hz)}",
            "InputFilter.decimation_factor=1",
            "InputFilter.filter_type=bandpass",
            "InputFilter.number_of_taps=31",
            "InputFilter.number_of_bands=2",
            "InputFilter.band1_begin=0.0",
            f"InputFilter.band1_end={_fmt_float(pass_edge)}",
            f"InputFilter.band2_begin={_fmt_float(pass_edge + 0.08)}",
            "InputFilter.band2_end=1.0",
            "InputFilter.ampl1_begin=1.0",
            "InputFilter.ampl1_end=1.0",
            "InputFilter.ampl2_begin=0.0",
            "InputFilter.ampl2_end=0.0",
            "InputFilter.band1_error=1.0",
            "InputFilter.band2_error=1.0",
            "InputFilter.grid_density=16",
            "InputFilter.dump=false",
        ]
    adapter = _DATA_TYPE_ADAPTER[item_type]
    adapter_lines = [f"DataTypeAdapter.implementation={adapter}"]
    if adapter == "Pass_Through":
        adapter_lines.append(f"DataTypeAdapter.item_type={item_type}")

    rate = str(output_rate_ms)
    lines = [
        "; GNSS-SDR 0.0.17 configuration written by semperfi.eval.gnss_sdr: GPS L1 C/A from a file",
        "[GNSS-SDR]",
        f"GNSS-SDR.internal_fs_sps={fs}",
        "",
        "SignalSource.implementation=File_Signal_Source",
        f"SignalSource.filename={data}",
        f"SignalSource.item_type={item_type}",
        f"SignalSource.sampling_frequency={fs}",
        "SignalSource.samples=0",
        "SignalSource.repeat=false",
        "SignalSource.enable_throttle_control=false",
        "SignalSource.dump=false",
        "",
        "SignalConditioner.implementation=Signal_Conditioner",
        *adapter_lines,
        *input_filter,
        "Resampler.implementation=Pass_Through",
        "Resampler.item_type=gr_complex",
        "",
        f"Channels_1C.count={channels}",
        "Channels.in_acquisition=1",
        "Channel.signal=1C",
        "",
        "Acquisition_1C.implementation=GPS_L1_CA_PCPS_Acquisition",
        "Acquisition_1C.item_type=gr_complex",
        "Acquisition_1C.coherent_integration_time_ms=1",
        "Acquisition_1C.pfa=0.01",
        f"Acquisition_1C.doppler_max={doppler_max_hz}",
        "Acquisition_1C.doppler_step=250",
        f"Acquisition_1C.max_dwells={int(max_dwells)}",
        "Acquisition_1C.blocking=true",
        "Acquisition_1C.dump=false",
        "",
        "Tracking_1C.implementation=GPS_L1_CA_DLL_PLL_Tracking",
        "Tracking_1C.item_type=gr_complex",
        "Tracking_1C.pll_bw_hz=35.0",
        "Tracking_1C.dll_bw_hz=2.0",
        "Tracking_1C.early_late_space_chips=0.5",
        "Tracking_1C.dump=false",
        "",
        "TelemetryDecoder_1C.implementation=GPS_L1_CA_Telemetry_Decoder",
        "TelemetryDecoder_1C.dump=false",
        "",
        "Observables.implementation=Hybrid_Observables",
        "Observables.dump=false",
        "",
        "PVT.implementation=RTKLIB_PVT",
        "PVT.positioning_mode=Single",
        f"PVT.iono_model={iono_model}",
        f"PVT.trop_model={trop_model}",
        f"PVT.elevation_mask={_fmt_float(float(elevation_mask_deg))}",
        f"PVT.output_rate_ms={rate}",
        "PVT.display_rate_ms=1000",
        "PVT.output_enabled=true",
        f"PVT.output_path={out}",
        f"PVT.rinex_output_enabled={'true' if rinex else 'false'}",
        "PVT.rinex_version=3",
        f"PVT.rinex_output_path={out}",
        "PVT.xml_output_enabled=false",
        "PVT.rtcm_output_file_enabled=false",
        "PVT.an_output_enabled=false",
        "PVT.nmea_output_file_enabled=true",
        f"PVT.nmea_output_file_path={out}",
        f"PVT.nmea_dump_filename={NMEA_NAME}",
        f"PVT.nmea_rate_ms={rate}",
        "PVT.kml_output_enabled=true",
        f"PVT.kml_output_path={out}",
        f"PVT.kml_rate_ms={rate}",
        "PVT.gpx_output_enabled=true",
        f"PVT.gpx_output_path={out}",
        f"PVT.gpx_rate_ms={rate}",
        "PVT.geojson_output_enabled=true",
        f"PVT.geojson_output_path={out}",
        f"PVT.geojson_rate_ms={rate}",
        "PVT.flag_nmea_tty_port=false",
        "PVT.flag_rtcm_server=false",
        "PVT.flag_rtcm_tty_port=false",
        "PVT.enable_monitor=false",
        "PVT.dump=false",
        f"PVT.dump_filename={OUTPUT_STEM}",
        "",
    ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------------- NMEA

def _nmea(sentence: str, kind: str):
    """The parsed $Gx<kind> sentence (pynmeagps, checksum verified), or None when it is not one or is corrupt."""
    sentence = sentence.strip()
    if not re.match(rf"^\$[A-Z]{{2}}{kind},", sentence):
        return None
    try:
        return NMEAReader.parse(sentence, validate=VALCKSUM)
    except (NMEAParseError, NMEATypeError, ValueError):
        return None


def parse_gga(sentence: str) -> Fix | None:
    """The fix in one $GxGGA sentence, or None when it is not one, is corrupt, or reports no fix (quality 0)."""
    msg = _nmea(sentence, "GGA")
    if msg is None or not msg.quality or msg.lat == "" or msg.lon == "" or not msg.time:
        return None
    lat, lon = float(msg.lat), float(msg.lon)
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        return None
    t = msg.time
    seconds = t.second + t.microsecond * 1e-6
    number = lambda v, default: default if v == "" else float(v)   # noqa: E731 -- empty fields are pynmeagps' ""
    return Fix(t_utc=f"{t.hour:02d}:{t.minute:02d}:{seconds:06.3f}", t_sod_s=t.hour * 3600 + t.minute * 60 + seconds,
               lat_deg=lat, lon_deg=lon, height_m=number(msg.alt, 0.0) + number(msg.sep, 0.0),
               n_sats=int(number(msg.numSV, 0)), hdop=number(msg.HDOP, float("nan")))


def read_nmea_fixes(nmea_path: str | os.PathLike) -> list[Fix]:
    """Every valid GGA fix in an NMEA file, in file order, dated by the RMC sentence of the same epoch."""
    fixes = []
    dates: dict = {}   # RMC time -> date; GNSS-SDR writes RMC just before GGA
    with open(nmea_path, "r", encoding="ascii", errors="replace") as f:
        for line in f:
            rmc = _nmea(line, "RMC")
            if rmc is not None and rmc.date and rmc.time:
                dates = {rmc.time: rmc.date.isoformat()}
                continue
            fix = parse_gga(line)
            if fix is not None:
                fixes.append(replace(fix, date_utc=dates.get(_nmea(line, "GGA").time, "")))
    return fixes


# GNSS-SDR's console: which satellite a channel took, and when a channel let it go
_TRACKING_STARTED = re.compile(r"Tracking of GPS L1 C/A signal started on channel (\d+) for satellite GPS PRN (\d+)")
_LOCK_LOST = re.compile(r"Loss of lock in channel (\d+)!")


def lock_losses(log_path: str | os.PathLike) -> dict[int, int]:
    """Per PRN, how often a GNSS-SDR run lost its lock (its console log: each loss names a channel, the channel's
    satellite the one it last started tracking). A filter that leaves what a tracking loop stumbles on shows here
    before it shows in the fixes. A missing or unreadable log gives nothing."""
    try:
        text = Path(log_path).read_text(encoding="utf-8", errors="replace")
    except OSError:
        return {}
    satellite: dict[str, int] = {}
    lost: dict[int, int] = {}
    for line in text.splitlines():
        if (started := _TRACKING_STARTED.search(line)) is not None:
            satellite[started.group(1)] = int(started.group(2))
        elif (loss := _LOCK_LOST.search(line)) is not None and loss.group(1) in satellite:
            prn = satellite[loss.group(1)]
            lost[prn] = lost.get(prn, 0) + 1
    return lost


# ----------------------------------------------------------------------------------------------------- run

def gnss_sdr_version(exe: str = GNSS_SDR_EXE) -> str:
    """'gnss-sdr version 0.0.17' or similar; RuntimeError when it is not installed."""
    path = shutil.which(exe)
    if path is None:
        raise RuntimeError(f"{exe} not found on PATH; install it (Debian/Ubuntu: apt-get install -y gnss-sdr)")
    out = subprocess.run([path, "--version"], stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=30)
    return (out.stdout + out.stderr).strip().splitlines()[0] if (out.stdout or out.stderr) else "unknown"


def _log_tail(log_path: Path, n_lines: int = 15) -> str:
    try:
        lines = log_path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return ""
    return "\n".join(lines[-n_lines:])


def run_gnss_sdr(data_file: str | os.PathLike, fs_hz: float, item_type: str, if_hz: float,
                 out_dir: str | os.PathLike, timeout_s: float, info_log: bool = False,
                 **config_kwargs) -> list[Fix]:
    """Run GNSS-SDR on `data_file` in `out_dir` (config, log, NMEA/GPX/KML/GeoJSON all land there) and return
    its fixes. It runs with cwd=out_dir, stdin closed and the keyboard listener off, and ends by itself at the end
    of the file. Raises RuntimeError when gnss-sdr is missing or fails, TimeoutError after `timeout_s`.
    GNSS-SDR's own glog files keep warnings and errors only unless `info_log` (INFO is some MB a minute).
    `config_kwargs` go to gnss_sdr_config (channels, trop_model, iono_model, output_rate_ms, ...)."""
    exe = shutil.which(GNSS_SDR_EXE)
    if exe is None:
        raise RuntimeError(f"{GNSS_SDR_EXE} not found on PATH; install it (Debian/Ubuntu: apt-get install -y gnss-sdr)")
    data_file = Path(data_file).resolve()
    if not data_file.is_file():
        raise FileNotFoundError(f"IQ file not found: {data_file}")
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    for ext in ("nmea", "kml", "gpx", "geojson"):   # a previous run's fixes must not be read as this run's
        for stale in out_dir.glob(f"{OUTPUT_STEM}*.{ext}"):
            stale.unlink()
    conf_path = out_dir / CONFIG_NAME
    # its outputs relative to the directory it runs in: GNSS-SDR cuts a long output path short (at about 170
    # characters) and writes its NMEA file into a sibling directory of that shorter name; and its samples through a
    # link there of a short name: a 194-character path to them was cut short too, and it could not open them
    conf_path.write_text(gnss_sdr_config(_short_link(data_file, out_dir), fs_hz, item_type, if_hz, out_dir=".",
                                         **config_kwargs), encoding="utf-8")
    log_path = out_dir / LOG_NAME
    cmd = [exe, f"--config_file={conf_path}", "--keyboard=false", f"--log_dir={out_dir}",
           f"--minloglevel={0 if info_log else 1}"]
    started_s = time.time()
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=out_dir, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        try:
            rc = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            _stop(proc)
            raise TimeoutError(f"gnss-sdr did not finish within {timeout_s:g} s; log: {log_path}") from None
        except BaseException:   # Ctrl-C: do not leave a receiver running
            _stop(proc)
            raise
    if rc != 0 or NOT_STARTED in _log_tail(log_path):   # (it exits with 0 when it cannot start its flowgraph)
        raise RuntimeError(f"gnss-sdr exited with status {rc}; log: {log_path}\n{_log_tail(log_path)}")
    # GNSS-SDR deletes its NMEA file again when it never wrote a fix: no file means no fix.
    fixes: list[Fix] = []
    for nmea in sorted(out_dir.glob("*.nmea")):
        if nmea.stat().st_mtime >= started_s - 1.0:   # written by this run (other .nmea files are left alone)
            fixes.extend(read_nmea_fixes(nmea))
    return fixes


def _short_link(data_file: Path, out_dir: Path) -> str:
    """The samples as GNSS-SDR opens them from out_dir (its working directory): through SAMPLES_LINK there, or by
    their full path where no link can be made."""
    link = out_dir / SAMPLES_LINK
    try:
        link.unlink(missing_ok=True)
        link.symlink_to(data_file)
    except OSError:
        return str(data_file)
    return SAMPLES_LINK


def _stop(proc: subprocess.Popen, grace_s: float = 5.0) -> None:
    """SIGINT the receiver's process group (it then closes its files), SIGKILL it if it lingers."""
    for sig, wait_s in ((signal.SIGINT, grace_s), (signal.SIGKILL, grace_s)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


# ----------------------------------------------------------------------------------------------------- errors

def fixes_ecef(fixes) -> np.ndarray:
    """(n, 3) ECEF positions (m) of fixes with lat_deg, lon_deg, height_m (WGS-84, pymap3d)."""
    if len(fixes) == 0:
        return np.zeros((0, 3))
    return np.column_stack(pymap3d.geodetic2ecef(np.array([f.lat_deg for f in fixes], dtype=float),
                                                 np.array([f.lon_deg for f in fixes], dtype=float),
                                                 np.array([f.height_m for f in fixes], dtype=float)))


def horizontal_errors_m(fixes, lat_deg: float, lon_deg: float, height_m: float = 0.0) -> np.ndarray:
    """Horizontal distance (m) of each fix from a place, in the place's local tangent plane (metrics.errors)."""
    from .metrics import errors
    place = np.array(pymap3d.geodetic2ecef(lat_deg, lon_deg, height_m))
    return errors(fixes_ecef(fixes), np.tile(place, (len(fixes), 1))).horizontal_m


def error_summary_m(errors_m: np.ndarray) -> dict:
    """mean, 95th percentile and max of an error array (nan when empty)."""
    e = np.asarray(errors_m, dtype=float)
    if e.size == 0:
        return {"mean": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"mean": float(e.mean()), "p95": float(np.percentile(e, 95)), "max": float(e.max())}

"""The scenario's sections and keys, each with its default, unit and domain (semperfi.config), and the checks across
keys that refuse impossible scenarios with one clear line."""

from dataclasses import dataclass

from .. import config
from ..config import key

FORMAT_NOISE_RMS = {"ibyte": 20.0, "ishort": 2000.0, "gr_complex": 1.0, "cfloat": 1.0,
                    "byte": 20.0, "short": 2000.0, "float": 1.0}   # the last three: real samples at signal.if_hz
REAL_FORMATS = ("byte", "short", "float")
PRN = (1, 32)


@dataclass(frozen=True)
class Time:
    start: str = key("", doc="GPS time 'YYYY-MM-DDTHH:MM:SS'; empty = the ephemerides' reference epoch")
    duration_s: float = key(60.0, 1e-3, 86400.0, unit="s")


@dataclass(frozen=True)
class Signal:
    fs_hz: float = key(4e6, 0.5e6, 100e6, unit="Hz")
    if_hz: float = key(0.0, -50e6, 50e6, unit="Hz", doc="below half the sample rate (checked across keys)")
    format: str = key("ishort", choices=tuple(FORMAT_NOISE_RMS),
                      doc="byte, short and float are real, at signal.if_hz")
    noise_rms: float = key(0.0, 0.0, 1e6, doc="noise RMS per I/Q component in output units; 0 = the format's default")
    seed: int = key(1)


@dataclass(frozen=True)
class Constellation:
    rinex: str = key("", doc="RINEX 2/3 navigation file; empty = a synthesized 31-satellite constellation")
    elevation_mask_deg: float = key(5.0, -5.0, 89.9, unit="deg")
    cn0_dbhz: float = key(45.0, 15.0, 70.0, unit="dB-Hz")
    cn0_model: str = key("constant", choices=("constant", "elevation"),
                         doc="elevation: lower C/N0 towards the horizon")
    prns: tuple = key([], *PRN, each=True, doc="restrict to these PRNs; empty = every satellite above the mask")
    max_satellites: int = key(12, 1, 32)
    ionosphere: bool = key(True, doc="Klobuchar delay with the broadcast coefficients")
    troposphere: bool = key(True, doc="Saastamoinen delay in a standard atmosphere")


@dataclass(frozen=True)
class Receiver:
    lat_deg: float = key(42.3398, -90.0, 90.0, unit="deg", doc="Northeastern University, Boston")
    lon_deg: float = key(-71.0892, -180.0, 360.0, unit="deg")
    height_m: float = key(10.0, -1000.0, 1e6, unit="m")
    trajectory: str = key("", doc="CSV at 10 Hz, gps-sdr-sim style: t_s,x,y,z (ECEF) or t_s,lat,lon,h (with -lla)")
    trajectory_lla: bool = key(False)
    clock_bias_s: float = key(2.5e-4, -1e-2, 1e-2, unit="s")
    clock_drift_s_s: float = key(5e-8, -1e-5, 1e-5, unit="s/s")


@dataclass(frozen=True)
class Attacker:
    enabled: bool = key(False)
    mode: str = key("static", choices=("static", "push", "takeover", "meaconing", "time_push"))
    start_s: float = key(0.0, 0.0, 86400.0, unit="s", doc="attack start, from the first sample")
    power_advantage_db: float = key(6.0, -3.0, 20.0, unit="dB")
    prns: tuple = key([], *PRN, each=True, doc="spoofed PRNs; empty = every PRN visible at the claimed position")
    offset_east_m: float = key(1000.0, -1e7, 1e7, unit="m", doc="static: claimed = true start position + offset")
    offset_north_m: float = key(0.0, -1e7, 1e7, unit="m")
    offset_up_m: float = key(0.0, -1e7, 1e7, unit="m")
    push_speed_m_s: float = key(5.0, 0.0, 1e4, unit="m/s", doc="push/takeover: drag-off speed of the claimed position")
    push_azimuth_deg: float = key(90.0, -360.0, 360.0, unit="deg")
    push_hold_s: float = key(5.0, 0.0, 86400.0, unit="s",
                             doc="takeover, time_push: seconds aligned before the drag-off (the push) begins")
    max_offset_m: float = key(5000.0, 0.0, 1e7, unit="m")
    power_ramp_s: float = key(10.0, 0.0, 86400.0, unit="s",
                              doc="takeover, time_push: seconds to ramp from ramp_start_db to the full advantage")
    ramp_start_db: float = key(-10.0, -60.0, 20.0, unit="dB")
    # the spoofer's clock error, common to every spoofed PRN: 0 = synchronized to GPS time, as a competent attacker
    # is (5e-6: an unsynchronised spoofer)
    time_offset_s: float = key(0.0, -1e-3, 1e-3, unit="s")
    delay_s: float = key(2e-6, 0.0, 0.999e-3, unit="s", doc="meaconing: the replay delay")
    # time_push: a sky-aligned copy of every signal (code and carrier), delayed by this rate x (t - start_s -
    # push_hold_s): the position stays, the clock walks (TEXBAT-style; 25 ns/s), up to max_offset_m / c
    time_push_rate_s_s: float = key(2.5e-8, 0.0, 1e-5, unit="s/s")
    time_push_ramp_s: float = key(5.0, 0.0, 86400.0, unit="s",
                                  doc="time_push: the rate grows linearly from 0 over these seconds (0: a step)")
    nav_data: str = key("same", choices=("same", "altered"),
                        doc="altered: spoofed PRNs broadcast a shifted satellite clock")
    altered_clock_s: float = key(1e-6, -1e-2, 1e-2, unit="s")
    carrier_offset_hz: float = key(0.0, -1e4, 1e4, unit="Hz", doc="spoofer oscillator frequency error")
    copies: int = key(1, 1, 10, doc="spoofed copies of each PRN (a hostile many-peak attacker)")
    copy_spacing_s: float = key(3e-6, 0.0, 1e-3, unit="s", doc="extra delay between successive copies")


@dataclass(frozen=True)
class Multipath:
    enabled: bool = key(False)
    delay_chips: float = key(0.25, 0.001, 1022.0, unit="chips", doc="a short echo of every (or the listed) signal")
    relative_power_db: float = key(-6.0, -60.0, 0.0, unit="dB")
    prns: tuple = key([], *PRN, each=True)


@dataclass(frozen=True)
class Output:
    truth_rate_hz: float = key(10.0, 0.01, 1000.0, unit="Hz")


SECTIONS = {"time": Time, "signal": Signal, "constellation": Constellation, "receiver": Receiver,
            "attacker": Attacker, "multipath": Multipath, "output": Output}
DEFAULTS: dict = config.defaults(SECTIONS)


def load_scenario(path=None, sets=()) -> dict:
    """The effective scenario, checked; ValueError with one line when a value is impossible."""
    cfg = config.load(DEFAULTS, path, sets)
    check(cfg)
    return cfg


def check(cfg: dict) -> None:
    """Every key within its domain, then what no single key can say."""
    config.check(cfg, SECTIONS)
    s = cfg["signal"]
    if abs(s["if_hz"]) >= s["fs_hz"] / 2:
        raise ValueError(f"impossible scenario: signal.if_hz = {s['if_hz']:g} must be below half the sample rate")
    if s["format"] in REAL_FORMATS and s["if_hz"] == 0:
        raise ValueError(f"impossible scenario: signal.format = '{s['format']}' is real-valued: set signal.if_hz "
                         "(between 0 and half the sample rate)")

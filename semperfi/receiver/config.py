"""The receiver's configuration: its sections and keys, each with its default, unit and domain (TOML, overridable
with --set section.key=value; semperfi.config)."""

from dataclasses import dataclass

from .. import config
from ..config import key

OUTPUT_FORMATS = ("csv", "nmea", "gpx", "geojson", "rinex")


@dataclass(frozen=True)
class Acquisition:
    prns: tuple = key([], 1, 32, each=True, doc="PRNs searched; empty = 1..32")
    doppler_max_hz: float = key(6000.0, 100.0, 50000.0, unit="Hz")
    doppler_step_hz: float = key(0.0, 0.0, 5000.0, unit="Hz", doc="0 = two thirds of 1 / coherent time")
    coherent_ms: int = key(2, 1, 20, unit="ms")
    noncoherent: int = key(5, 1, 1000, doc="coherent sums added in power")
    pfa: float = key(1e-3, 1e-12, 0.5, doc="false-alarm probability of one PRN's whole search")
    max_peaks: int = key(8, 1, 64)
    reacquire_s: float = key(5.0, 0.1, 3600.0, unit="s", doc="how often untracked PRNs are searched again")
    cross_correlation_db: float = key(10.0, 0.0, 60.0, unit="dB",
                                      doc="a peak this much weaker than another PRN's, at its Doppler, is cross-talk")


@dataclass(frozen=True)
class Tracking:
    channels: int = key(12, 1, 64)
    pll_bw_hz: float = key(18.0, 0.5, 100.0, unit="Hz")
    fll_bw_hz: float = key(10.0, 0.5, 100.0, unit="Hz")
    dll_bw_hz: float = key(2.0, 0.05, 20.0, unit="Hz")
    spacing_chips: float = key(0.5, 0.05, 1.0, unit="chips", doc="early-late spacing")
    pull_in_ms: int = key(500, 0, 10000, unit="ms")
    min_cn0_dbhz: float = key(25.0, 0.0, 60.0, unit="dB-Hz")


@dataclass(frozen=True)
class Pvt:
    rate_hz: float = key(10.0, 0.01, 100.0, unit="Hz")
    elevation_mask_deg: float = key(5.0, -10.0, 90.0, unit="deg")
    ionosphere: bool = key(True)
    troposphere: bool = key(True)
    smoothing_s: float = key(20.0, 0.0, 1000.0, unit="s", doc="carrier smoothing (Hatch filter); 0 = off")


@dataclass(frozen=True)
class Integrity:                    # RAIM (receiver/integrity.py)
    pfa: float = key(1e-5, 1e-12, 0.5, doc="false-alarm probability of the residual test, per fix")
    pmd: float = key(1e-3, 1e-12, 0.5, doc="missed-detection probability for the protection levels")
    exclude: bool = key(True, doc="fault exclusion (else detection only)")
    max_exclusions: int = key(1, 1, 12, doc="ranges excluded at most: the protection levels bound one fault; a sky "
                                            "that needs more excluded fails the test")
    integration_s: float = key(0.001, 0.001, 0.02, unit="s", doc="DLL coherent integration in the code-noise model")
    floor_m: float = key(0.5, 0.0, 1000.0, unit="m", doc="orbit/clock/receiver error floor (1 sigma)")
    atmosphere_m: float = key(0.5, 0.0, 1000.0, unit="m",
                              doc="residual atmosphere at zenith (1 sigma), / sin(elevation)")


@dataclass(frozen=True)
class Output:
    formats: tuple = key(list(OUTPUT_FORMATS), choices=OUTPUT_FORMATS, each=True)


SECTIONS = {"acquisition": Acquisition, "tracking": Tracking, "pvt": Pvt, "integrity": Integrity, "output": Output}
DEFAULTS: dict = config.defaults(SECTIONS)

"""The receiver's configuration keys with their defaults (TOML, overridable with --set section.key=value)."""

DEFAULTS: dict = {
    "acquisition": {
        "prns": [],                 # empty = 1..32
        "doppler_max_hz": 6000.0,
        "doppler_step_hz": 0.0,     # 0 = two thirds of 1 / coherent time
        "coherent_ms": 2,
        "noncoherent": 5,
        "pfa": 1e-3,                # false-alarm probability of one PRN's whole search
        "max_peaks": 8,
        "reacquire_s": 5.0,         # how often untracked PRNs are searched again
        "cross_correlation_db": 10.0,  # a peak this much weaker than another PRN's, at its Doppler, is cross-talk
    },
    "tracking": {
        "channels": 12,
        "pll_bw_hz": 18.0,
        "fll_bw_hz": 10.0,
        "dll_bw_hz": 2.0,
        "spacing_chips": 0.5,
        "pull_in_ms": 500,
        "min_cn0_dbhz": 25.0,
    },
    "pvt": {
        "rate_hz": 10.0,
        "elevation_mask_deg": 5.0,
        "ionosphere": True,
        "troposphere": True,
        "smoothing_s": 20.0,        # carrier smoothing (Hatch filter) of pseudoranges; 0 = off
    },
    "integrity": {                  # RAIM (receiver/integrity.py)
        "pfa": 1e-5,                # false-alarm probability of the residual test, per fix
        "pmd": 1e-3,                # missed-detection probability for the protection levels
        "exclude": True,            # fault exclusion (else detection only)
        "integration_s": 0.001,     # DLL coherent integration in the code-noise model
        "floor_m": 0.5,             # orbit/clock/receiver error floor (1 sigma)
        "atmosphere_m": 0.5,        # residual atmosphere at zenith (1 sigma), / sin(elevation)
    },
    "output": {
        "formats": ["csv", "nmea", "gpx", "geojson", "rinex"],
    },
}

# Each key's domain, checked after every override: (low, high) inclusive, or a tuple of choices for lists/strings.
DOMAINS: dict = {
    "acquisition.prns": ("each", 1, 32),
    "acquisition.doppler_max_hz": (100.0, 50000.0),
    "acquisition.doppler_step_hz": (0.0, 5000.0),
    "acquisition.coherent_ms": (1, 20),
    "acquisition.noncoherent": (1, 1000),
    "acquisition.pfa": (1e-12, 0.5),
    "acquisition.max_peaks": (1, 64),
    "acquisition.reacquire_s": (0.1, 3600.0),
    "acquisition.cross_correlation_db": (0.0, 60.0),
    "tracking.channels": (1, 64),
    "tracking.pll_bw_hz": (0.5, 100.0),
    "tracking.fll_bw_hz": (0.5, 100.0),
    "tracking.dll_bw_hz": (0.05, 20.0),
    "tracking.spacing_chips": (0.05, 1.0),
    "tracking.pull_in_ms": (0, 10000),
    "tracking.min_cn0_dbhz": (0.0, 60.0),
    "pvt.rate_hz": (0.01, 100.0),
    "pvt.elevation_mask_deg": (-10.0, 90.0),
    "pvt.smoothing_s": (0.0, 1000.0),
    "integrity.pfa": (1e-12, 0.5),
    "integrity.pmd": (1e-12, 0.5),
    "integrity.exclude": ("one", True, False),
    "integrity.integration_s": (0.001, 0.02),
    "integrity.floor_m": (0.0, 1000.0),
    "integrity.atmosphere_m": (0.0, 1000.0),
    "output.formats": ("each", "csv", "nmea", "gpx", "geojson", "rinex"),
}

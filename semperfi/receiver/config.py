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
        "formats": ["csv", "nmea", "gpx", "geojson"],
    },
}

"""The conventional receiver chain: acquisition, tracking, navigation, observables, PVT, outputs."""

from ..face import lazy_face

# the names other rooms use, by the module that gives them (loaded when first used)
__all__, __getattr__, __dir__ = lazy_face(__name__, {
    "acquisition": ("Caf", "DopplerGrid", "Peak", "acquire"),
    "carried_time": ("Donor", "carried", "donor"),
    "chain": ("Receiver",),
    "chisquare": ("chi2_isf",),
    "clock": ("ClockModel", "ClockNoise", "Innovation", "LAGS_S"),
    "cn0": ("correlate_ms",),
    "config": ("DEFAULTS", "SECTIONS"),
    "correlator": ("CodeBank", "MAX_SUB_SAMPLES", "code_bank", "fill_lanes", "lane_buffer", "replica",
                   "sub_block_samples"),
    "fix_stream": ("FixStream", "RATE_HZ"),
    "gps_input": ("MavlinkGpsOut",),
    "integrity": ("pbias", "trusted"),
    "interference": ("Monitor",),
    "navigation": ("NavDecoder",),
    "nmea_out": ("NmeaOut",),
    "outputs": ("EventLog",),
    "plots": ("plot_before_after", "plot_cafs"),
    "run": ("NoSignal", "run_file"),
    "tracking": ("Channel", "LoopConfig", "NEXT_SAMPLE", "initial_state"),
    "types": ("Fix", "TRUSTED_STATES"),
    "workers": ("cores", "run_aside", "run_each"),
})

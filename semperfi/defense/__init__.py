"""SemperFi's defence: spoofing detection, adversarial peak choice, the Legitimate Signal Retriever (SIC)."""

from ..face import lazy_face

# the names other rooms use, by the module that gives them (loaded when first used)
__all__, __getattr__, __dir__ = lazy_face(__name__, {
    "canceller": ("Canceller", "CancellerConfig", "caf_amplitude", "refine_peak"),
    "clean": ("clean_file",),
    "config": ("load_config",),
    "defended": ("DefendedReceiver",),
    "guard": ("SpoofGuard",),
    "identifier": ("MIN_SIGNATURE_M", "PAPER_THRESHOLD_M"),
    "imu_track": ("read_imu_csv",),
    "twopath": ("delay_profile",),
})

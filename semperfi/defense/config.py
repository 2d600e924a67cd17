"""The defence's configuration keys with their defaults (section [defense] of the receiver's TOML)."""

DEFAULTS: dict = {
    "defense": {
        "mode": "full",             # off | detect | full
        "examine_every_s": 1.0,     # re-acquisition for auxiliary peaks while tracking, as the paper does
        "startup_s": 0.3,           # output held back at the start while the first looks (every 0.1 s) decide, so an
                                    # attack present from the first sample is cancelled from the first sample
        "full_search_every_s": 10.0,  # every PRN is searched this often; in between, only those seen
        "separation_ns": 500.0,
        "confirmations": 2,
        "adversarial": "auto",      # auto | stronger | later | prn:LIST (the identifier will decide from a maneuver)
        "max_iterations": 3,        # SIC stages per PRN
        "max_tracks": 24,           # spoofed signals cancelled at once, all PRNs together
        "verify_after_s": 1.0,      # re-acquisition on the cleaned signal this long after a cancellation starts
        "rectify": "auto",          # auto | always | off: the pseudorange rectifier times a retrieved legitimate signal
                                    # by its spoofer's navigation message (auto: when it cannot read its own)
        "min_redundancy": 2,        # a recovered fix has at least 4 + this many satellites: its integrity test can
                                    # both detect and exclude one bad range
    },
}

# Each key's domain (see receiver/config.py): (low, high) inclusive, or choices.
DOMAINS: dict = {
    "defense.mode": ("one", "off", "detect", "full"),
    "defense.examine_every_s": (0.01, 3600.0),
    "defense.startup_s": (0.0, 60.0),
    "defense.full_search_every_s": (0.1, 3600.0),
    "defense.separation_ns": (0.0, 1e6),
    "defense.confirmations": (1, 100),
    "defense.max_iterations": (1, 16),
    "defense.max_tracks": (1, 256),
    "defense.verify_after_s": (0.0, 3600.0),
    "defense.min_redundancy": (1, 28),
    "defense.rectify": ("one", "auto", "always", "off"),
}


def load_config(path=None, sets=()) -> dict:
    """The receiver's configuration with the defence's section: the defaults, then the TOML file at path, then the
    --set overrides; every value checked against its domain (ValueError: one line naming the key)."""
    from .. import config
    from ..receiver.config import DEFAULTS as RECEIVER, DOMAINS as RECEIVER_DOMAINS
    cfg = config.load({**RECEIVER, **DEFAULTS}, path, sets)
    config.check_domains(cfg, {**RECEIVER_DOMAINS, **DOMAINS})
    return cfg

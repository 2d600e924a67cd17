"""The defence's configuration: section [defense] of the receiver's TOML, each key with its default, unit and
domain (semperfi.config)."""

from dataclasses import dataclass

from .. import config
from ..config import key


@dataclass(frozen=True)
class Defense:
    mode: str = key("full", choices=("off", "detect", "full"))
    # re-acquisition for auxiliary peaks while tracking, as the paper does: this often once an attack is seen or a
    # pair waits for its confirmation; quiet_examine_every_s while nothing at all has been seen (at a third of the
    # cost: its looks are half as long), so that the defence costs little on a clean sky
    examine_every_s: float = key(0.5, 0.01, 3600.0, unit="s")
    quiet_examine_every_s: float = key(2.0, 0.01, 3600.0, unit="s")
    # once every PRN alarmed is cancelled and verified and nothing waits on the looks, the attack is watched this often
    settled_examine_every_s: float = key(1.0, 0.01, 3600.0, unit="s")
    # output held back at the start while the first looks (every 0.1 s) decide, so an attack present from the first
    # sample is cancelled from the first sample
    startup_s: float = key(0.3, 0.0, 60.0, unit="s")
    full_search_every_s: float = key(10.0, 0.1, 3600.0, unit="s",
                                     doc="every PRN is searched this often; in between, only those seen")
    separation_ns: float = key(500.0, 0.0, 1e6, unit="ns")
    confirmations: int = key(2, 1, 100)
    adversarial: str = key("auto", doc="auto | stronger | later | prn:LIST (the identifier decides from a "
                                       "maneuver); checked by the policy")
    max_iterations: int = key(3, 1, 16, doc="SIC stages per PRN")
    max_tracks: int = key(24, 1, 256, doc="spoofed signals cancelled at once, all PRNs together (`clean` takes "
                                          "those past it out, one path each)")
    verify_after_s: float = key(1.0, 0.0, 3600.0, unit="s",
                                doc="re-acquisition on the cleaned signal this long after a cancellation starts")
    # the pseudorange rectifier times a retrieved legitimate signal by its spoofer's navigation message (auto: when
    # it cannot read its own)
    rectify: str = key("auto", choices=("auto", "always", "off"))
    # a recovered fix has at least 4 + this many satellites: its integrity test can both detect and exclude one bad
    # range
    min_redundancy: int = key(2, 1, 28)


SECTIONS = {"defense": Defense}
DEFAULTS: dict = config.defaults(SECTIONS)


def load_config(path=None, sets=()) -> dict:
    """The receiver's configuration with the defence's section: the defaults, then the TOML file at path, then the
    --set overrides; every value checked against its domain (ValueError: one line naming the key)."""
    from ..receiver import SECTIONS as RECEIVER
    sections = {**RECEIVER, **SECTIONS}
    cfg = config.load(config.defaults(sections), path, sets)
    config.check(cfg, sections)
    return cfg

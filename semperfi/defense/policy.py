"""Which of a PRN's two peaks is the attacker's, until the Adversarial Peak Identifier decides from a maneuver."""

import math
from dataclasses import dataclass

from ..gps import chips_apart, chips_offset
from ..receiver import Peak
from .detector import Alarm


@dataclass(frozen=True)
class Choice:
    adversarial: Peak
    legitimate: Peak | None   # None when the legitimate peak is not in sight (hidden under a strong attacker's)
    guessed: bool          # True when nothing but the policy's assumption says so
    reason: str


def _later(a: Peak, b: Peak) -> bool:
    """Whether a arrives later than b: a larger delay is a smaller code phase at the same instant."""
    return chips_offset(a.code_phase_chips, b.code_phase_chips) < 0


def parse_policy(text: str) -> tuple[str, frozenset[int]]:
    """'auto' | 'stronger' | 'later' | 'prn:3,7,19'; ValueError (one line) otherwise."""
    if text in ("auto", "stronger", "later"):
        return text, frozenset()
    if text.startswith("prn:"):
        try:
            prns = frozenset(int(p) for p in text[4:].split(",") if p.strip())
        except ValueError:
            prns = frozenset()
        if prns and all(1 <= p <= 32 for p in prns):
            return "prn", prns
    raise ValueError(f"--adversarial wants auto, stronger, later or prn:LIST (e.g. prn:3,7); got '{text}'")


def choose(alarm: Alarm, policy: str, prns: frozenset[int] = frozenset()) -> Choice | None:
    """The adversarial peak of an alarm's pair under a policy; None when the policy leaves this PRN alone."""
    main, aux = alarm.pair.main, alarm.pair.auxiliary
    stronger, weaker = (main, aux) if main.metric >= aux.metric else (aux, main)
    if policy == "prn" and alarm.prn not in prns:
        return None
    if policy == "auto" and alarm.newcomer_code_phase_chips is not None:
        newcomer = min((main, aux), key=lambda p: chips_apart(p.code_phase_chips, alarm.newcomer_code_phase_chips))
        other = aux if newcomer is main else main
        return Choice(newcomer, other, False, "appeared after the receiver had the other peak")
    if policy == "later":
        late, early = (main, aux) if _later(main, aux) else (aux, main)
        return Choice(late, early, True, "assumed: the later-arriving peak is the attacker's")
    reason = {"prn": "listed PRN; assumed: the stronger peak is the attacker's"}.get(
        policy, "assumed: the stronger peak is the attacker's (no earlier lock to tell them apart)")
    return Choice(stronger, weaker, True, reason)


POWER_MARGIN_DB = 2.0   # a pair closer in power than this is not told apart by one look's peak metrics


def by_power(alarm: Alarm, attacker_stronger: bool, reason: str) -> Choice:
    """The attacker's peak by a power relation the maneuver established on other PRNs (not a guess: one
    transmitter, one relation, and the attacker cannot know in advance which PRNs the maneuver leaves undecided).
    A pair whose two peaks are too close in power for one look's metrics to apply it is still assumed on the
    relation's side, a guess: the stronger-peak assumption would go against what the maneuver showed (GPS-SDR-SIM,
    an attacker 3 dB under: a twin 0.4 chip from its spoofer, first seen after the verdict, fitted within 2 dB)."""
    main, aux = alarm.pair.main, alarm.pair.auxiliary
    stronger, weaker = (main, aux) if main.metric >= aux.metric else (aux, main)
    gap = gap_db(stronger, weaker)
    close = gap < POWER_MARGIN_DB
    if close:
        reason = f"{reason}; assumed here, where the two peaks are {gap:.1f} dB apart (within {POWER_MARGIN_DB:g} dB)"
    return Choice(stronger, weaker, close, reason) if attacker_stronger else Choice(weaker, stronger, close, reason)


def gap_db(adversarial: Peak, legitimate: Peak) -> float:
    """How much stronger the attacker's peak is than its twin (dB; negative: weaker), by their metrics."""
    return 10 * math.log10(max(adversarial.metric, 1e-9) / max(legitimate.metric, 1e-9))


def power_relation(gaps_db: dict[int, float]) -> bool | None:
    """Whether the attacker's peak is the stronger, from PRNs where its peak is known (PRN -> gap_db): one answer on
    three or more, each clear of the noise of one look's metrics; None otherwise."""
    relation = {g > 0 for g in gaps_db.values()}
    if len(gaps_db) >= 3 and len(relation) == 1 and min(map(abs, gaps_db.values())) >= POWER_MARGIN_DB / 2:
        return relation.pop()
    return None

"""The pseudorange rectifier (the paper's section 3.4, equations 11-13): a legitimate signal retrieved from under a
strong spoofer, but too disturbed to read its own navigation message, takes its transmit time from the spoofer's.

The canceller follows every spoofed signal with a tracking channel; its data bits are decoded here like any
satellite's (the spoofer's TOW and, without assistance, its ephemeris). A stealthy attacker moves a position by the
signals' times of arrival and keeps the navigation data, so at any receive instant the legitimate signal's transmit
time is the spoofer's plus the offset of the two code phases:

    t_l = t_at + (phase_l - phase_at)    with  phase_l - phase_at  known modulo one code period (1 ms)

The whole milliseconds come from the receiver's own clock when it has one (the last fix predicts every satellite's
transmit time to well under half a millisecond: coarse time), else from the paper's assumption that the spoofer
keeps within half a millisecond of GPS time. Verify before trusting: a spoofer whose time is whole milliseconds or
seconds away from the receiver's prediction is refused, and the rectified ranges go through the same integrity test
(RAIM) as every other fix -- the attacker may alter the navigation data too.
"""

from dataclasses import dataclass

from ..gps import CA_CODE_LENGTH_CHIPS, CA_CODE_PERIOD_S, SECONDS_PER_WEEK, chips_offset, wrap_week_s
from ..receiver import Channel, Donor, NavDecoder, carried, donor
from .canceller import AdversaryTrack, Canceller

MODES = ("auto", "always", "off")
MAX_TIME_STEP_S = 0.010        # a spoofer's time this far from the receiver's prediction or further is refused


@dataclass(frozen=True)
class Rectified:
    t_sv_s: float              # the legitimate signal's transmit time at the sample
    ephemeris: object
    offset_s: float            # t_l - t_at: the spoofer's time of arrival less the legitimate one's
    adversary_stage: int


class Rectifier:
    """Decodes every spoofed signal the canceller follows, and rectifies the legitimate channels of the same PRNs."""

    def __init__(self, mode: str = "auto", week_hint: int | None = None):
        if mode not in MODES:
            raise ValueError(f"defense.rectify wants one of {', '.join(MODES)}; got '{mode}'")
        self.mode, self.week_hint = mode, week_hint
        self._decoders: dict[AdversaryTrack, NavDecoder] = {}
        self.refused: dict[int, str] = {}      # PRN -> why its spoofer's time was not taken (latest)
        # PRN -> (sample of a code epoch, its transmit time, Doppler): a receiver channel that tracked the spoofer
        # and read its time before the canceller took the signal over
        self._donors: dict[int, Donor] = {}
        self._inherited: dict[AdversaryTrack, tuple[int, float]] = {}   # track -> (code period, its transmit time)

    def inherit(self, prn: int, channel: Channel, decoder: NavDecoder | None) -> None:
        """A receiver channel on the peak now being cancelled hands its time on: the canceller's fresh track of the
        same signal need not wait a subframe (6-12 s) to read it again (receiver/carried_time)."""
        given = donor(channel, decoder)
        if given is not None:
            self._donors[prn] = given

    def update(self, canceller: Canceller) -> None:
        """Read the data bits every spoofer's channel has completed (call after each push through the canceller)."""
        live = {tr for st in canceller.stages for tr in st.tracks.values()}
        self._decoders = {tr: dec for tr, dec in self._decoders.items() if tr in live}
        self._inherited = {tr: a for tr, a in self._inherited.items() if tr in live}
        for tr in live:
            dec = self._decoders.setdefault(tr, NavDecoder(tr.prn, self.week_hint))
            soft, first = tr.channel.take_bits()
            if soft.size:
                dec.push_bits(soft, first)
            if dec.time_anchor is None and tr not in self._inherited and tr.prn in self._donors:
                self._take_over(tr)

    def _take_over(self, tr: AdversaryTrack) -> None:
        """The donor's time carried to the track's latest code epoch (receiver/carried_time)."""
        if tr.channel.ms < 2:
            return
        anchor = carried(tr.channel, self._donors[tr.prn])
        if anchor is None:
            del self._donors[tr.prn]
        else:
            self._inherited[tr] = anchor

    def _time_anchor(self, tr: AdversaryTrack, dec: NavDecoder) -> tuple[int, float] | None:
        """(code period, its transmit time) of a track: from its own decoded message, else inherited."""
        if dec.time_anchor is not None:
            start_bit, t0 = dec.time_anchor
            return tr.channel.ms_of_bit(start_bit), t0
        return self._inherited.get(tr)

    @property
    def week(self) -> int | None:
        """The GPS week from any spoofer's subframe 1 (a stealthy attacker keeps the navigation data)."""
        return next((dec.week for dec in self._decoders.values() if dec.week is not None), None)

    def ephemeris(self, prn: int):
        """A spoofer's decoded ephemeris of a PRN (provisional: a stealthy attacker keeps the navigation data)."""
        return next((dec.ephemeris for tr, dec in self._decoders.items()
                     if tr.prn == prn and dec.ephemeris is not None), None)

    def wants(self, prn: int, has_own_time: bool) -> bool:
        """Whether a channel's range is to be rectified: always (mode always), or when it cannot say its own
        transmit time (auto); only for PRNs whose spoofer is being followed."""
        if self.mode == "off" or (self.mode == "auto" and has_own_time):
            return False
        return any(tr.prn == prn for tr in self._decoders)

    def rectify(self, prn: int, legit: Channel, sample: float, ephemeris_of, predict) -> Rectified | None:
        """The legitimate channel's transmit time at an absolute sample, from the spoofer it was retrieved from.

        ephemeris_of(prn, tow_s): the receiver's own ephemeris (assisted or decoded), else the spoofer's is used;
        predict(ephemeris, sample): the receiver clock's prediction of the transmit time, or None without a fix."""
        for tr, dec in sorted(self._decoders.items(), key=lambda item: item[0].stage):
            anchor = self._time_anchor(tr, dec) if tr.prn == prn else None
            if anchor is None:
                continue
            adv = tr.channel
            t_at = adv.transmit_time_at(sample, *anchor)
            at_chips, legit_chips = adv.code_phase_at(sample), legit.code_phase_at(sample)
            if t_at is None or at_chips is None or legit_chips is None:
                continue
            offset = chips_offset(legit_chips, at_chips) / CA_CODE_LENGTH_CHIPS * CA_CODE_PERIOD_S
            t_sv = (t_at + offset) % SECONDS_PER_WEEK
            eph = ephemeris_of(prn, t_sv) or dec.ephemeris
            if eph is None:
                continue
            predicted = predict(eph, sample)
            if predicted is not None:
                whole = round(wrap_week_s(predicted - t_sv) / CA_CODE_PERIOD_S) * CA_CODE_PERIOD_S
                if abs(whole) >= MAX_TIME_STEP_S:
                    self.refused[prn] = f"{whole * 1e3:+.0f} ms from the receiver clock's prediction"
                    return None
                offset += whole
                t_sv = (t_sv + whole) % SECONDS_PER_WEEK
            self.refused.pop(prn, None)
            return Rectified(t_sv, eph, offset, tr.stage)
        return None

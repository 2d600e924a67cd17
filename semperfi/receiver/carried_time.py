"""A channel's time handed on to the next channel of the same satellite, so that it need not read a subframe (6-12 s)
before its range counts again.

A code epoch leaves the satellite on a whole millisecond of its time. The time a channel last read, carried at its
Doppler to a new channel's code epoch, is off by the change of the range since (a spoofer's drag, a time push, the
receiver's motion, the Doppler's error over the gap: microseconds over seconds); rounded to the whole millisecond it
is exact while that stays under half a millisecond (150 km). It is then the new channel's own signal's time, whichever
of a PRN's signals it locked on: the rounding takes the whole milliseconds from the old one, the code phase the rest.
With no old one (a PRN dropped because its peak is being cancelled, a satellite rising, a donor out of reach), the
receiver's own clock -- what a recent fix predicts -- gives the whole milliseconds the same way.
"""

from dataclasses import dataclass

from ..gps import CA_CODE_PERIOD_S, L1_HZ, SECONDS_PER_WEEK
from .navigation import NavDecoder
from .tracking import Channel

# A channel with neither its own time nor a donor takes the whole milliseconds of a code epoch from the receiver's
# clock (a hot start): exact while what a fix predicts is off by under half a millisecond (150 km). A fix this old, on
# a vehicle at 40 m/s with its clock drift 10 m/s off, predicts within 12 km (40 us).
CLOCK_TIME_MAX_AGE_S = 300.0
# A donor's time is carried this far: its Doppler's error (some Hz) moves a code epoch by well under a microsecond
# over it, nothing next to the half millisecond the carried time is rounded by.
DONOR_REACH_S = 5.0


@dataclass(frozen=True)
class Donor:
    """A code epoch of a channel that knew its time: its absolute sample, its transmit time, the Doppler there."""
    epoch_sample: float
    t_sv_s: float
    doppler_hz: float

    def reaches(self, sample: float, fs_hz: float) -> bool:
        """Whether its time may still be carried to this absolute sample (DONOR_REACH_S)."""
        return abs(sample - self.epoch_sample) <= DONOR_REACH_S * fs_hz


def donor(channel: Channel, decoder: NavDecoder | None) -> Donor | None:
    """What a channel that read its own time (bit sync and a HOW) hands on; None when it had none."""
    if decoder is None or decoder.time_anchor is None or channel.bits.edge_ms is None or channel.ms < 2:
        return None
    ms = channel.ms - 2   # an epoch with one after it in the history
    start_bit, t0 = decoder.time_anchor
    return Donor(float(channel.epoch_sample[ms % channel.HISTORY_MS]),
                 t0 + (ms - channel.ms_of_bit(start_bit)) * CA_CODE_PERIOD_S, channel.doppler_at(0))


def carried(channel: Channel, given: Donor) -> tuple[int, float] | None:
    """(code period, its transmit time) of a channel from a donor's time: at its latest code epoch with one after it
    in the history; None while it has none, or when the donor is further than DONOR_REACH_S."""
    latest = latest_epoch(channel)
    if latest is None:
        return None
    ms, epoch = latest
    if not given.reaches(epoch, channel.fs_hz):
        return None
    t_sv = given.t_sv_s + (epoch - given.epoch_sample) / channel.fs_hz * (1.0 + given.doppler_hz / L1_HZ)
    return on_whole_ms(ms, t_sv)


def latest_epoch(channel: Channel) -> tuple[int, float] | None:
    """A channel's latest code epoch with one after it in the history: (code period, absolute sample); None before
    it has two."""
    if channel.ms < 2:
        return None
    ms = channel.ms - 2
    return ms, float(channel.epoch_sample[ms % channel.HISTORY_MS])


def on_whole_ms(ms: int, t_sv_s: float) -> tuple[int, float]:
    """(code period, its transmit time) from a transmit time carried or predicted to that code epoch: the epoch
    leaves the satellite on a whole millisecond, the nearest one."""
    return ms, round(t_sv_s / CA_CODE_PERIOD_S) * CA_CODE_PERIOD_S % SECONDS_PER_WEEK

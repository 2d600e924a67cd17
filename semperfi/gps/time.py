"""GPS time: weeks, seconds of week, and conversions to calendar time (GPS time has no leap seconds)."""

from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

from .constants import SECONDS_PER_WEEK

GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)


@dataclass(frozen=True, order=True)
class GpsTime:
    """An instant of GPS time as full week number and seconds of week."""
    week: int
    tow_s: float

    @classmethod
    def from_seconds(cls, gps_seconds: float) -> "GpsTime":
        week, tow = divmod(gps_seconds, SECONDS_PER_WEEK)
        return cls(int(week), float(tow))

    @classmethod
    def from_datetime(cls, when: datetime) -> "GpsTime":
        """A calendar date read as GPS time (no leap-second shift, as RINEX navigation epochs are)."""
        if when.tzinfo is None:
            when = when.replace(tzinfo=timezone.utc)
        return cls.from_seconds((when - GPS_EPOCH).total_seconds())

    @property
    def seconds(self) -> float:
        """Seconds since the GPS epoch."""
        return self.week * SECONDS_PER_WEEK + self.tow_s

    def to_datetime(self) -> datetime:
        return GPS_EPOCH + timedelta(seconds=self.seconds)

    def __add__(self, dt_s: float) -> "GpsTime":
        # added to the seconds of week, not to the seconds since 1980 (~1.3e9 s, whose float steps are 0.24 us): the
        # simulator's truth times each sample to well under a nanosecond
        week, tow = divmod(self.tow_s + dt_s, SECONDS_PER_WEEK)
        return GpsTime(self.week + int(week), float(tow))


def wrap_week_s(dt_s: float) -> float:
    """A time difference folded into +/- half a week (IS-GPS-200 20.3.3.4.3, the tk correction)."""
    half = SECONDS_PER_WEEK / 2
    if dt_s > half:
        return dt_s - SECONDS_PER_WEEK
    if dt_s < -half:
        return dt_s + SECONDS_PER_WEEK
    return dt_s

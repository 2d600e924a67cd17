"""RINEX 3.04 observation files (GPS L1 C/A: C1C, L1C, D1C, S1C) from the receiver's observables, so a run can be
post-processed with RTKLIB or compared with another receiver's observations.

Times are GPS time (TIME OF FIRST OBS says GPS). Values the receiver does not have (carrier phase before the PLL
has a count) are left blank, as RINEX allows.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, TextIO

from .. import __version__
from ..gps import GPS_EPOCH

OBS_TYPES = ("C1C", "L1C", "D1C", "S1C")


@dataclass(frozen=True)
class ObsEpoch:
    """One epoch: the GPS time of reception and, per PRN, (pseudorange m, carrier phase cycles or nan, Doppler Hz,
    C/N0 dB-Hz)."""
    gps_week: int
    gps_tow_s: float
    sats: dict[int, tuple[float, float, float, float]]


def _gps_datetime(week: int, tow_s: float) -> _dt.datetime:
    return GPS_EPOCH + _dt.timedelta(weeks=int(week), seconds=float(tow_s))


def _line(text: str, label: str) -> str:
    return f"{text:<60.60s}{label:<20s}\n"


def _value(v: float) -> str:
    """F14.3 plus blank LLI and signal strength flags; blank when unknown or beyond the field."""
    if v is None or not math.isfinite(v) or abs(v) >= 1e10:
        return " " * 16
    return f"{v:14.3f}  "


def write_header(f: TextIO, first: ObsEpoch, marker: str = "SEMPERFI", approx_xyz_m=(0.0, 0.0, 0.0)) -> None:
    t = _gps_datetime(first.gps_week, first.gps_tow_s)
    # The file's date is the first observation's, not the wall clock's: the same input gives the same file.
    made = t.strftime("%Y%m%d %H%M%S GPS")
    f.write(_line(f"{3.04:9.2f}{'':11s}{'O':1s}{'':19s}{'G':1s}", "RINEX VERSION / TYPE"))
    f.write(_line(f"{'semperfi ' + __version__:<20.20s}{'':20s}{made:<20.20s}", "PGM / RUN BY / DATE"))
    f.write(_line(marker[:60], "MARKER NAME"))
    f.write(_line(f"{'':20s}{'':40s}", "OBSERVER / AGENCY"))
    f.write(_line(f"{'':20s}{'SEMPERFI SDR':<20s}{__version__:<20.20s}", "REC # / TYPE / VERS"))
    f.write(_line(f"{'':20s}{'':20s}", "ANT # / TYPE"))
    f.write(_line("".join(f"{v:14.4f}" for v in approx_xyz_m), "APPROX POSITION XYZ"))
    f.write(_line("".join(f"{0.0:14.4f}" for _ in range(3)), "ANTENNA: DELTA H/E/N"))
    f.write(_line(f"G  {len(OBS_TYPES):3d}" + "".join(f" {o:3s}" for o in OBS_TYPES), "SYS / # / OBS TYPES"))
    sec = t.second + t.microsecond * 1e-6
    f.write(_line(f"{t.year:6d}{t.month:6d}{t.day:6d}{t.hour:6d}{t.minute:6d}{sec:13.7f}{'':5s}GPS",
                  "TIME OF FIRST OBS"))
    f.write(_line("", "END OF HEADER"))


def write_epoch(f: TextIO, epoch: ObsEpoch) -> None:
    t = _gps_datetime(epoch.gps_week, epoch.gps_tow_s)
    sec = t.second + t.microsecond * 1e-6
    prns = sorted(epoch.sats)
    f.write(f"> {t.year:4d} {t.month:02d} {t.day:02d} {t.hour:02d} {t.minute:02d}{sec:11.7f}  0{len(prns):3d}\n")
    for prn in prns:
        f.write(f"G{prn:02d}" + "".join(_value(v) for v in epoch.sats[prn]).rstrip() + "\n")


class RinexObsWriter:
    """Streams epochs into a RINEX observation file as the receiver produces them: the header goes out with the
    first epoch (it needs the first time and an approximate position), every epoch is flushed, so a run cut short
    leaves a readable file."""

    def __init__(self, path: str | os.PathLike, marker: str = "SEMPERFI"):
        self.path, self.marker = Path(path), marker
        self._f: TextIO | None = None
        self.n_epochs = 0

    def write(self, epoch: ObsEpoch, approx_xyz_m=(0.0, 0.0, 0.0)) -> None:
        if self._f is None:
            self._f = open(self.path, "w", encoding="ascii")
            write_header(self._f, epoch, self.marker, approx_xyz_m)
        write_epoch(self._f, epoch)
        self._f.flush()
        self.n_epochs += 1

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None


def write_rinex_obs(path: str | os.PathLike, epochs: Iterable[ObsEpoch], marker: str = "SEMPERFI",
                    approx_xyz_m=(0.0, 0.0, 0.0)) -> Path:
    """Write every epoch (GPS time order, as the receiver produces them) to `path`; returns the path."""
    writer = RinexObsWriter(path, marker)
    try:
        for epoch in epochs:
            writer.write(epoch, approx_xyz_m)
    finally:
        writer.close()
    if writer.n_epochs == 0:
        raise ValueError("no observation epochs to write into RINEX")
    return writer.path

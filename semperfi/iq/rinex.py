"""RINEX 2/3 GPS navigation files -> broadcast ephemerides and ionosphere/UTC parameters.

Parsing is georinex's; this module only validates what it returns (a navigation file is input from outside and
may be garbled) and turns it into the plain types of `semperfi.gps`.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..gps import Ephemeris, GpsTime, IonoParams, UtcParams

MAX_NAV_FILE_BYTES = 64 * 1024 * 1024

# georinex variable -> Ephemeris field
_FIELDS = {
    "sqrtA": "sqrt_a_sqrt_m", "Eccentricity": "e", "Io": "i0_rad", "Omega0": "omega0_rad", "omega": "omega_rad",
    "M0": "m0_rad", "DeltaN": "delta_n_rad_s", "IDOT": "idot_rad_s", "OmegaDot": "omega_dot_rad_s",
    "Cuc": "cuc_rad", "Cus": "cus_rad", "Crc": "crc_m", "Crs": "crs_m", "Cic": "cic_rad", "Cis": "cis_rad",
    "SVclockBias": "af0_s", "SVclockDrift": "af1_s_s", "SVclockDriftRate": "af2_s_s2", "TGD": "tgd_s",
}


@dataclass(frozen=True)
class NavData:
    """All GPS ephemerides of a navigation file, with its header's ionosphere and UTC parameters."""
    ephemerides: tuple[Ephemeris, ...]
    iono: IonoParams | None
    utc: UtcParams | None

    def nearest(self, prn: int, t: GpsTime) -> Ephemeris | None:
        """The healthy ephemeris of PRN whose toe is nearest to t (within its 4 h validity), or None."""
        best, best_dt = None, 4 * 3600.0 + 1
        for eph in self.ephemerides:
            if eph.prn != prn or eph.health != 0:
                continue
            dt = abs(GpsTime(eph.week, eph.toe_s).seconds - t.seconds)
            if dt < best_dt:
                best, best_dt = eph, dt
        return best


def _header(path: Path) -> tuple[IonoParams | None, UtcParams | None]:
    alpha = beta = utc = None
    leap = 0
    with path.open("r", errors="replace") as f:
        for _ in range(200):
            line = f.readline()
            if not line or "END OF HEADER" in line:
                break
            label, body = line[60:].strip(), line[:60].replace("D", "E").replace("d", "e")
            try:
                if label == "ION ALPHA":
                    alpha = tuple(float(body[2 + 12 * i: 14 + 12 * i]) for i in range(4))
                elif label == "ION BETA":
                    beta = tuple(float(body[2 + 12 * i: 14 + 12 * i]) for i in range(4))
                elif label == "IONOSPHERIC CORR" and body[:4] in ("GPSA", "GPSB"):
                    vals = tuple(float(body[5 + 12 * i: 17 + 12 * i]) for i in range(4))
                    alpha, beta = (vals, beta) if body[:4] == "GPSA" else (alpha, vals)
                elif label == "DELTA-UTC: A0,A1,T,W":
                    utc = (float(body[3:22]), float(body[22:41]), int(body[41:50]), int(body[50:59]))
                elif label == "TIME SYSTEM CORR" and body[:4] == "GPUT":
                    utc = (float(body[5:22]), float(body[22:38]), int(body[38:45]), int(body[45:50]))
                elif label == "LEAP SECONDS":
                    leap = int(body[:6])
            except ValueError:
                raise ValueError(f"{path}: malformed header line '{label}'") from None
    iono = IonoParams(alpha, beta) if alpha and beta else None
    utc_params = None
    if utc:
        a0, a1, tot, wnt = utc
        utc_params = UtcParams(a0, a1, tot, wnt % 256, leap, wnt % 256, 7, leap)
    return iono, utc_params


def _plausible(eph: Ephemeris) -> bool:
    values = np.array([getattr(eph, f) for f in _FIELDS.values()] + [eph.toe_s, eph.toc_s])
    return (bool(np.all(np.isfinite(values))) and 4000.0 < eph.sqrt_a_sqrt_m < 6000.0 and 0.0 <= eph.e < 0.1
            and 0.0 <= eph.toe_s < 604800.0 and abs(eph.af0_s) < 1e-2)


def read_rinex_nav(path: str | Path) -> NavData:
    """Read the GPS records of a RINEX 2 or 3 navigation file; ValueError (one line) if there are none."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"RINEX navigation file not found: {path}")
    if path.stat().st_size > MAX_NAV_FILE_BYTES:
        raise ValueError(f"{path}: larger than {MAX_NAV_FILE_BYTES // 2**20} MiB, not a navigation file")
    iono, utc = _header(path)
    try:
        import georinex
        nav = georinex.load(path, use="G")
    except Exception as exc:   # a garbled file can fail anywhere inside the parser
        raise ValueError(
            f"{path}: not a readable RINEX GPS navigation file ({type(exc).__name__}: {exc})"[:300]) from None
    if nav is None or "sv" not in getattr(nav, "coords", {}) or "sqrtA" not in nav:
        raise ValueError(f"{path}: no GPS navigation records")
    # plain arrays (time x sv): indexing the xarray dataset record by record costs seconds per file
    cols = {v: nav[v].transpose("time", "sv").values for v in ("sqrtA", "GPSWeek", "Toe", "IODE", "IODC", "health",
                                                              "FitIntvl", *_FIELDS) if v in nav}
    times = [GpsTime.from_datetime(np.datetime64(t, "us").astype(object)) for t in nav.time.values]
    ephemerides = []
    for j, sv in enumerate(nav.sv.values):
        if not str(sv).startswith("G"):
            continue
        for ti, toc in enumerate(times):
            if not np.isfinite(cols["sqrtA"][ti, j]):
                continue
            try:
                eph = Ephemeris(
                    prn=int(str(sv)[1:]), week=int(cols["GPSWeek"][ti, j]), toe_s=float(cols["Toe"][ti, j]),
                    toc_s=toc.tow_s, iode=int(cols["IODE"][ti, j]), iodc=int(cols["IODC"][ti, j]),
                    health=int(cols["health"][ti, j]),
                    fit_interval_flag=int(cols["FitIntvl"][ti, j] > 4.0) if "FitIntvl" in cols else 0,
                    **{f: float(cols[v][ti, j]) if v in cols else 0.0 for v, f in _FIELDS.items()})
            except (ValueError, OverflowError):
                continue
            if _plausible(eph):
                ephemerides.append(eph)
    if not ephemerides:
        raise ValueError(f"{path}: no valid GPS ephemeris in the file")
    return NavData(tuple(ephemerides), iono, utc)

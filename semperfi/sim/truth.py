"""The truth log written beside every simulated file: receiver state, per-signal observables, attack events."""

import csv
import json
from pathlib import Path

import numpy as np

from ..gps import ecef_to_geodetic
from .simulate import ReceiverTruth, SignalTruth

RECEIVER_COLUMNS = ["t_rx_s", "gps_week", "gps_tow_s", "lat_deg", "lon_deg", "height_m", "x_m", "y_m", "z_m",
                    "vx_m_s", "vy_m_s", "vz_m_s", "clock_bias_s", "clock_drift_s_s",
                    "claimed_lat_deg", "claimed_lon_deg", "claimed_height_m", "claimed_delay_s"]
SIGNAL_COLUMNS = ["t_rx_s", "prn", "source", "code_phase_chips", "doppler_hz", "carrier_phase_cycles", "cn0_dbhz",
                  "pseudorange_m", "elevation_deg"]


def truth_paths(out_path: str | Path) -> dict[str, Path]:
    """Where the truth of OUT.bin goes: OUT.truth-receiver.csv, OUT.truth-signals.csv, OUT.truth-events.jsonl."""
    stem = Path(out_path).with_suffix("")
    return {k: stem.parent / f"{stem.name}.truth-{k}" for k in ("receiver.csv", "signals.csv", "events.jsonl")}


class TruthLog:
    """Writes the three truth files, flushing every record so a run cut short keeps what it produced."""

    def __init__(self, out_path: str | Path):
        paths = truth_paths(out_path)
        self._files = [open(paths[k], "w", newline="") for k in ("receiver.csv", "signals.csv", "events.jsonl")]
        self._receiver, self._signals = csv.writer(self._files[0]), csv.writer(self._files[1])
        self._receiver.writerow(RECEIVER_COLUMNS)
        self._signals.writerow(SIGNAL_COLUMNS)

    def record(self, rx: ReceiverTruth, signals: list[SignalTruth]) -> None:
        lat, lon, h = ecef_to_geodetic(rx.pos_ecef_m)
        claimed = [""] * 3
        if rx.claimed_ecef_m is not None:
            clat, clon, ch = ecef_to_geodetic(rx.claimed_ecef_m)
            claimed = [f"{np.degrees(clat):.9f}", f"{np.degrees(clon):.9f}", f"{ch:.3f}"]
        self._receiver.writerow([f"{rx.t_rx_s:.6f}", rx.gps_week, f"{rx.gps_tow_s:.9f}", f"{np.degrees(lat):.9f}",
                                 f"{np.degrees(lon):.9f}", f"{h:.3f}", *(f"{v:.3f}" for v in rx.pos_ecef_m),
                                 *(f"{v:.4f}" for v in rx.vel_ecef_m_s), f"{rx.clock_bias_s:.12e}",
                                 f"{rx.clock_drift_s_s:.6e}", *claimed,
                                 "" if rx.claimed_delay_s is None else f"{rx.claimed_delay_s:.12e}"])
        for s in signals:
            self._signals.writerow([f"{s.t_rx_s:.6f}", s.prn, s.source, f"{s.code_phase_chips:.6f}",
                                    f"{s.doppler_hz:.4f}", f"{s.carrier_phase_cycles:.6f}",
                                    "off" if not np.isfinite(s.cn0_dbhz) else f"{s.cn0_dbhz:.2f}",
                                    f"{s.pseudorange_m:.4f}", f"{s.elevation_deg:.3f}"])
        for f in self._files[:2]:
            f.flush()

    def event(self, event: dict) -> None:
        self._files[2].write(json.dumps(event) + "\n")
        self._files[2].flush()

    def close(self) -> None:
        for f in self._files:
            f.close()


def read_signal_truth(path: str | Path) -> list[dict]:
    """The rows of a signals truth file, numbers as floats (cn0 'off' as -inf)."""
    rows = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            rows.append({k: (row[k] if k == "source" else
                             (-np.inf if row[k] == "off" else float(row[k]))) for k in SIGNAL_COLUMNS})
    return rows

"""INS-only track files for ``semperfi run --imu TRACK.csv`` and finding the maneuver inside a long track.

TRACK.csv: header ``t_s,north_m,east_m,down_m``; ``t_s`` from the first sample of the recording, origin anywhere.
The file is hostile input: size, row count, finiteness and increasing time are checked; errors raise ValueError
with one clear line.
"""
from __future__ import annotations

import csv

import numpy as np

from semperfi.defense.identifier import ImuTrack

MAX_BYTES = 64 * 1024 * 1024
COLUMNS = ("t_s", "north_m", "east_m", "down_m")
DRIFT_ROUNDS = 3   # fits of the INS's velocity drift on what is still, each from the previous one's stillness


def read_imu_csv(path) -> ImuTrack:
    with open(path, "rb") as f:
        raw = f.read(MAX_BYTES + 1)
    if len(raw) > MAX_BYTES:
        raise ValueError(f"{path}: IMU track larger than {MAX_BYTES} bytes")
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: IMU track is not ASCII text") from None
    rows = list(csv.reader(text.splitlines()))
    if not rows or tuple(c.strip() for c in rows[0]) != COLUMNS:
        raise ValueError(f"{path}: IMU track header must be {','.join(COLUMNS)}")
    values = []
    for n, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != 4:
            raise ValueError(f"{path}:{n}: expected 4 columns, got {len(row)}")
        try:
            values.append([float(c) for c in row])
        except ValueError:
            raise ValueError(f"{path}:{n}: not a number") from None
    a = np.array(values, dtype=float).reshape(-1, 4)
    if len(a) < 2:
        raise ValueError(f"{path}: IMU track needs at least 2 rows")
    try:
        return ImuTrack(a[:, 0], a[:, 1], a[:, 2], a[:, 3])
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None


def find_maneuver(track: ImuTrack, speed_threshold_mps: float = 0.8, min_duration_s: float = 3.0,
                  pad_s: float = 0.5) -> tuple[float, float] | None:
    """(start_s, end_s) of the longest stretch moving faster than the threshold (hover, maneuver, hover), the INS's
    velocity drift taken out: a line in time per axis (an accelerometer bias's), fitted on the stretches found still
    and found again. An INS 5 mm/s^2 off reads 0.8 m/s some 100 s into a hover: untaken, a long hover after the
    maneuver was the longest stretch 'moving', and its window the one identified."""
    v3 = track.velocity_at(track.t_s)
    # smooth over ~1 s so INS noise does not split the maneuver
    dt = float(np.median(np.diff(track.t_s)))
    k = max(1, int(round(1.0 / dt)))
    drift = np.zeros_like(v3)
    for _ in range(DRIFT_ROUNDS):
        v = np.convolve(np.linalg.norm(v3 - drift, axis=1), np.ones(k) / k, mode="same")
        still = v <= speed_threshold_mps
        if np.count_nonzero(still) < 2 * k or np.ptp(track.t_s[still]) < min_duration_s:
            break
        slope, offset = np.polyfit(track.t_s[still], v3[still], 1)
        drift = np.outer(track.t_s, slope) + offset
    moving = v > speed_threshold_mps
    best = None
    i = 0
    while i < len(moving):
        if moving[i]:
            j = i
            while j + 1 < len(moving) and moving[j + 1]:
                j += 1
            if best is None or track.t_s[j] - track.t_s[i] > best[1] - best[0]:
                best = (float(track.t_s[i]), float(track.t_s[j]))
            i = j + 1
        else:
            i += 1
    if best is None or best[1] - best[0] < min_duration_s:
        return None
    return max(best[0] - pad_s, float(track.t_s[0])), min(best[1] + pad_s, float(track.t_s[-1]))

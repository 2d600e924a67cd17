"""The closed loop's world: a multicopter behind its MAVLink endpoint, and the GPS signals (with the attacker's)
rendered chunk by chunk from where that vehicle truly is, written as IQ samples to a stream (a receiver's stdin).

The vehicle's clock is the signal's: chunk k covers [k, k+1) x CHUNK_S of both, and the vehicle takes its physics
steps (answering MAVLink) between chunks. Nothing waits on the wall clock: a receiver slower than real time simply
slows the world down (the pipe pushes back), and the flight side keys its commands on the vehicle's time_boot_ms.
The attacker is the scenario's (static, or on its own trajectory): the vehicle's maneuver moves the legitimate
signals, not the spoofer's claimed position. The truth (vehicle position per chunk) goes to a CSV beside.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pymap3d

from ..gps import enu_rotation
from ..iq import IqWriter, as_format, encode_samples
from .mavlink_vehicle import PHYSICS_HZ, MavlinkVehicle
from .simulate import CHUNK_S, make_live_simulator


def run_world(cfg: dict, out: BinaryIO, mavlink_port: int, truth_path: str | Path, seed: int = 0,
              altitude_m: float = 50.0, scale: float = 1.0, tee_path: str | Path | None = None) -> int:
    """Render cfg's scenario around the live vehicle into `out` (cfg's signal.format); returns chunks written.
    tee_path: also keep the samples in a recording (with its SigMF sidecar), for other receivers afterwards."""
    sim, motion = make_live_simulator(cfg)
    r = cfg["receiver"]
    lat, lon, h = r["lat_deg"], r["lon_deg"], r["height_m"]
    # the vehicle starts at the scenario's receiver position, altitude_m above its ground point
    vehicle = MavlinkVehicle(mavlink_port, seed=seed, origin=(lat, lon, h - altitude_m), altitude_m=altitude_m)
    rot_ned = enu_rotation(np.radians(lat), np.radians(lon))[[1, 0, 2]] * np.array([[1], [1], [-1]])   # ECEF -> NED
    fmt = as_format(cfg["signal"]["format"])
    steps = int(round(CHUNK_S * PHYSICS_HZ))
    written = 0
    tee = IqWriter(tee_path, fmt, sim.fs_hz, if_hz=sim.if_hz, scale=scale, description="SemperFi closed-loop world",
                   datetime_utc=sim.t0.to_datetime().isoformat()) if tee_path else None
    with open(truth_path, "w", newline="") as f:
        truth = csv.writer(f, lineterminator="\n")
        truth.writerow(["t_s", "north_m", "east_m", "down_m", "lat_deg", "lon_deg", "height_m"])
        try:
            for k, chunk in enumerate(sim.chunks()):
                items, _ = encode_samples(chunk, fmt, scale)
                out.write(items.tobytes())
                if tee is not None:
                    tee.write(chunk)
                written += 1
                for _ in range(steps):
                    vehicle.step()
                v = vehicle.vehicle
                n, e, d = v.pos_ned_m + np.array([0.0, 0.0, altitude_m])   # relative to the start
                plat, plon, ph = pymap3d.ned2geodetic(n, e, d, lat, lon, h)
                pos = np.array(pymap3d.geodetic2ecef(plat, plon, ph))
                motion.set_state((k + 1) * CHUNK_S, pos, rot_ned.T @ v.vel_ned_mps, rot_ned.T @ v.accel_ned_mps2)
                truth.writerow([f"{(k + 1) * CHUNK_S:.1f}", f"{n:.3f}", f"{e:.3f}", f"{d:.3f}", f"{plat:.8f}",
                                f"{plon:.8f}", f"{ph:.3f}"])
                f.flush()
        except BrokenPipeError:
            pass   # the receiver stopped reading: the world ends with it
        finally:
            vehicle.close()
            if tee is not None:
                tee.close()
    return written

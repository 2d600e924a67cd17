"""A cross-generator case (semperfi.eval.xgen.Case) rendered by our own simulator instead of GPS-SDR-SIM: the same
place, start time, motion, attack and rate, so every evaluation that takes a Case runs on either generator.

Our simulator renders the scene and its attacker in one pass (with its own noise, seeded by the case), where
GPS-SDR-SIM renders two scenes that xgen mixes. Path loss becomes its elevation C/N0 model; the troposphere stays
out, as in GPS-SDR-SIM's scenes, so the receivers run with the same settings on both (xgen.RECEIVER_SETTINGS).
Without a navigation file the constellation is synthesized at the case's start (the receiver then decodes its
ephemerides from the signal).
"""

from __future__ import annotations

import math
from pathlib import Path

from ..sim import load_scenario, simulate_to_file
from .xgen import Case, recording_s


def scenario_sets(case: Case, nav_path: str | Path | None) -> list[str]:
    """The case as --set overrides of our simulator's scenario."""
    day, clock = case.date.split(",")
    sets = [f'time.start="{day.replace("/", "-")}T{clock}"', f"time.duration_s={recording_s(case)}",
            f"signal.fs_hz={case.fs_hz}", 'signal.format="ishort"', f"signal.seed={case.seed}",
            f'constellation.rinex="{nav_path or ""}"', f"constellation.cn0_dbhz={case.cn0_dbhz}",
            f'constellation.cn0_model="{"elevation" if case.path_loss else "constant"}"',
            "constellation.troposphere=false",
            f"receiver.lat_deg={case.place.lat_deg}", f"receiver.lon_deg={case.place.lon_deg}",
            f"receiver.height_m={case.place.height_m}", f'receiver.trajectory="{case.motion}"',
            # the sample clock is GPS time, as in GPS-SDR-SIM's scenes: the time truth (Case.truth) holds
            "receiver.clock_bias_s=0.0", "receiver.clock_drift_s_s=0.0",
            f"attacker.enabled={str(case.attacker).lower()}"]
    if not case.attacker:
        return sets
    az = math.radians(case.azimuth_deg)
    sets += [f"attacker.power_advantage_db={case.advantage_db}", f"attacker.start_s={case.spoof_start_s}",
             "attacker.power_ramp_s=0.0", f"attacker.push_azimuth_deg={case.azimuth_deg}"]
    if case.push_ns_per_s:                  # the sky itself, delayed from push_from_s at a step rate
        sets += ['attacker.mode="time_push"', f"attacker.push_hold_s={case.push_from_s}",
                 f"attacker.time_push_rate_s_s={case.push_ns_per_s * 1e-9}", "attacker.time_push_ramp_s=0.0"]
    elif case.spoof_motion:                 # aligned for the hold, then dragged along the azimuth
        sets += ['attacker.mode="takeover"', f"attacker.push_hold_s={case.takeover_hold_s}",
                 f"attacker.push_speed_m_s={case.takeover_m_s}"]
    else:
        sets += ['attacker.mode="static"', f"attacker.offset_east_m={case.offset_m * math.sin(az)}",
                 f"attacker.offset_north_m={case.offset_m * math.cos(az)}"]
    return sets


def render_case(case: Case, nav_path: str | Path | None, out: Path) -> Path:
    """The case's recording (int16 IQ with its SigMF sidecar and truth files), rendered by our simulator."""
    simulate_to_file(load_scenario(None, scenario_sets(case, nav_path)), out)
    return out

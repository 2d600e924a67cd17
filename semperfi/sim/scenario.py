"""Scenario keys with their defaults, and the checks that refuse impossible values with one clear line."""

from .. import config

DEFAULTS: dict = {
    "time": {
        "start": "",              # GPS time 'YYYY-MM-DDTHH:MM:SS'; empty = the ephemerides' reference epoch
        "duration_s": 60.0,
    },
    "signal": {
        "fs_hz": 4e6,
        "if_hz": 0.0,
        "format": "ishort",
        "noise_rms": 0.0,         # noise RMS per I/Q component in output units; 0 = the format's default
        "seed": 1,
    },
    "constellation": {
        "rinex": "",              # RINEX 2/3 navigation file; empty = a synthesized 31-satellite constellation
        "elevation_mask_deg": 5.0,
        "cn0_dbhz": 45.0,
        "cn0_model": "constant",  # constant | elevation (lower C/N0 towards the horizon)
        "prns": [],               # restrict to these PRNs; empty = every satellite above the mask
        "max_satellites": 12,
        "ionosphere": True,       # Klobuchar delay with the broadcast coefficients
        "troposphere": True,      # Saastamoinen delay in a standard atmosphere
    },
    "receiver": {
        "lat_deg": 42.3398,       # Northeastern University, Boston
        "lon_deg": -71.0892,
        "height_m": 10.0,
        "trajectory": "",         # CSV at 10 Hz, gps-sdr-sim style: t_s,x,y,z (ECEF) or t_s,lat,lon,h (with -lla)
        "trajectory_lla": False,
        "clock_bias_s": 2.5e-4,
        "clock_drift_s_s": 5e-8,
    },
    "attacker": {
        "enabled": False,
        "mode": "static",         # static | push | takeover | meaconing | time_push
        "start_s": 0.0,           # attack start, seconds from the first sample
        "power_advantage_db": 6.0,
        "prns": [],               # spoofed PRNs; empty = every PRN visible at the claimed position
        "offset_east_m": 1000.0,  # static: claimed position = true start position + this offset
        "offset_north_m": 0.0,
        "offset_up_m": 0.0,
        "push_speed_m_s": 5.0,    # push/takeover: drag-off speed of the claimed position
        "push_azimuth_deg": 90.0,
        "push_hold_s": 5.0,       # takeover, time_push: seconds aligned before the drag-off (the push) begins
        "max_offset_m": 5000.0,
        "power_ramp_s": 10.0,     # takeover, time_push: seconds to ramp from ramp_start_db to the full advantage
        "ramp_start_db": -10.0,
        "time_offset_s": 0.0,     # the spoofer's clock error, common to every spoofed PRN: 0 = synchronized to GPS
                                  # time, as a competent attacker is (5e-6: an unsynchronised spoofer)
        "delay_s": 2e-6,          # meaconing: the replay delay
        "time_push_rate_s_s": 2.5e-8,  # time_push: a sky-aligned copy of every signal (code and carrier), delayed
                                  # by this rate x (t - start_s - push_hold_s): the position stays, the clock walks
                                  # (TEXBAT-style; 25 ns/s), up to max_offset_m / c
        "time_push_ramp_s": 5.0,  # time_push: the rate grows linearly from 0 over these seconds (0: a step)
        "nav_data": "same",       # same | altered (spoofed PRNs broadcast a shifted satellite clock)
        "altered_clock_s": 1e-6,
        "carrier_offset_hz": 0.0, # spoofer oscillator frequency error
        "copies": 1,              # spoofed copies of each PRN (a hostile many-peak attacker)
        "copy_spacing_s": 3e-6,   # extra delay between successive copies
    },
    "multipath": {
        "enabled": False,
        "delay_chips": 0.25,      # a short echo of every (or the listed) legitimate signal
        "relative_power_db": -6.0,
        "prns": [],
    },
    "output": {
        "truth_rate_hz": 10.0,
    },
}

FORMAT_NOISE_RMS = {"ibyte": 20.0, "ishort": 2000.0, "gr_complex": 1.0, "cfloat": 1.0,
                    "byte": 20.0, "short": 2000.0, "float": 1.0}   # the last three: real samples at signal.if_hz
REAL_FORMATS = ("byte", "short", "float")


def load_scenario(path=None, sets=()) -> dict:
    """The effective scenario, checked; ValueError with one line when a value is impossible."""
    cfg = config.load(DEFAULTS, path, sets)
    check(cfg)
    return cfg


def check(cfg: dict) -> None:
    s, c, r, a = cfg["signal"], cfg["constellation"], cfg["receiver"], cfg["attacker"]

    def need(ok: bool, what: str) -> None:
        if not ok:
            raise ValueError(f"impossible scenario: {what}")

    need(0.5e6 <= s["fs_hz"] <= 100e6, f"signal.fs_hz = {s['fs_hz']:g} (0.5 to 100 MHz)")
    need(abs(s["if_hz"]) < s["fs_hz"] / 2, f"signal.if_hz = {s['if_hz']:g} must be below half the sample rate")
    need(s["format"] in FORMAT_NOISE_RMS, f"signal.format = '{s['format']}' (ibyte, ishort, gr_complex; real at an "
                                          "IF: byte, short, float)")
    need(s["format"] not in REAL_FORMATS or s["if_hz"] != 0,
         f"signal.format = '{s['format']}' is real-valued: set signal.if_hz (between 0 and half the sample rate)")
    need(0 <= s["noise_rms"] <= 1e6, f"signal.noise_rms = {s['noise_rms']:g} (0 = the format's default, up to 1e6)")
    need(0 < cfg["time"]["duration_s"] <= 86400, f"time.duration_s = {cfg['time']['duration_s']:g} (0 to 1 day)")
    need(-5 <= c["elevation_mask_deg"] < 90, "constellation.elevation_mask_deg must lie in [-5, 90)")
    need(15 <= c["cn0_dbhz"] <= 70, f"constellation.cn0_dbhz = {c['cn0_dbhz']:g} (15 to 70 dB-Hz)")
    need(c["cn0_model"] in ("constant", "elevation"), "constellation.cn0_model is constant or elevation")
    need(all(isinstance(p, int) and 1 <= p <= 32 for p in c["prns"]), "constellation.prns are PRNs 1-32")
    need(1 <= c["max_satellites"] <= 32, "constellation.max_satellites must lie in 1..32")
    need(-90 <= r["lat_deg"] <= 90 and -180 <= r["lon_deg"] <= 360, "receiver latitude/longitude out of range")
    need(-1000 <= r["height_m"] <= 1e6, "receiver.height_m out of range (-1 km to 1000 km)")
    need(abs(r["clock_bias_s"]) < 1e-2 and abs(r["clock_drift_s_s"]) < 1e-5, "receiver clock bias/drift too large")
    need(a["mode"] in ("static", "push", "takeover", "meaconing", "time_push"), f"attacker.mode = '{a['mode']}'")
    need(0 <= a["time_push_rate_s_s"] <= 1e-5, "attacker.time_push_rate_s_s must lie in [0, 1e-5] s/s")
    need(a["time_push_ramp_s"] >= 0, "attacker.time_push_ramp_s must not be negative")
    need(-3 <= a["power_advantage_db"] <= 20,
         f"attacker.power_advantage_db = {a['power_advantage_db']:g} (-3 to +20 dB)")
    need(all(isinstance(p, int) and 1 <= p <= 32 for p in a["prns"]), "attacker.prns are PRNs 1-32")
    need(a["start_s"] >= 0, "attacker.start_s must not be negative")
    need(a["push_speed_m_s"] >= 0 and a["max_offset_m"] >= 0, "attacker push speed and max offset must not be negative")
    need(0 <= a["delay_s"] < 1e-3, "attacker.delay_s must lie in [0, 1 ms)")
    need(a["power_ramp_s"] >= 0, "attacker.power_ramp_s must not be negative")
    need(a["nav_data"] in ("same", "altered"), "attacker.nav_data is same or altered")
    need(1 <= a["copies"] <= 10 and a["copy_spacing_s"] >= 0, "attacker.copies must lie in 1..10")
    m = cfg["multipath"]
    need(0 < m["delay_chips"] < 1023 and m["relative_power_db"] <= 0,
         "multipath: delay in (0, 1023) chips, power <= 0 dB")
    need(cfg["output"]["truth_rate_hz"] > 0, "output.truth_rate_hz must be positive")

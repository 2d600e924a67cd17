"""L1 C/A physics from IS-GPS-200: codes, navigation message, orbits, time. numpy only, no I/O."""

from ..face import lazy_face

# the names other rooms use, by the module that gives them (loaded when first used)
__all__, __getattr__, __dir__ = lazy_face(__name__, {
    "atmosphere": ("iono_delay_m", "troposphere_delay_m"),
    "codes": ("UNUSED_G2_DELAYS", "ca_code", "chips_apart", "chips_offset", "gold_code"),
    "constants": ("BITS_PER_SUBFRAME", "CA_CHIP_RATE_HZ", "CA_CODE_LENGTH_CHIPS", "CA_CODE_PERIOD_S", "CHIPS_PER_BIT",
                  "L1_HZ", "L1_WAVELENGTH_M", "NAV_BIT_RATE_HZ", "SECONDS_PER_WEEK", "SPEED_OF_LIGHT_M_S",
                  "SUBFRAME_S"),
    "ephemeris": ("Ephemeris", "IonoParams", "UtcParams", "satellite_clock", "satellite_position",
                  "satellite_position_velocity", "stack_ephemerides"),
    "geometry": ("azimuth_elevation", "ecef_to_geodetic", "enu_rotation", "geodetic_to_ecef", "light_time_range",
                 "rotate_earth"),
    "lnav": ("DecodedSubframe", "PREAMBLE", "SUBFRAMES_PER_WEEK", "check_parity", "decode_subframe",
             "ephemeris_from_subframes", "iono_utc_from_subframe", "quantize_ephemeris", "subframe_bits",
             "week_of_subframe1"),
    "time": ("GPS_EPOCH", "GpsTime", "wrap_week_s"),
})

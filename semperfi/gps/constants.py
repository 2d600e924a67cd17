"""Physical and system constants of IS-GPS-200 (values exactly as the interface specification fixes them)."""

SPEED_OF_LIGHT_M_S = 2.99792458e8
GM_EARTH_M3_S2 = 3.986005e14          # WGS 84 value used by the GPS control segment
OMEGA_EARTH_RAD_S = 7.2921151467e-5   # WGS 84 Earth rotation rate
F_RELATIVISTIC_S_SQRT_M = -4.442807633e-10  # F = -2 sqrt(mu) / c^2
GPS_PI = 3.1415926535898              # the value of pi the ICD uses for semicircles

L1_HZ = 1575.42e6
CA_CHIP_RATE_HZ = 1.023e6
CA_CODE_LENGTH_CHIPS = 1023
CA_CODE_PERIOD_S = 1e-3
NAV_BIT_RATE_HZ = 50
CHIPS_PER_BIT = CA_CODE_LENGTH_CHIPS * 20
L1_WAVELENGTH_M = SPEED_OF_LIGHT_M_S / L1_HZ

SECONDS_PER_WEEK = 604800
SUBFRAME_S = 6.0
BITS_PER_SUBFRAME = 300

"""Each satellite's continuous 50 bit/s LNAV stream, built a subframe at a time and cached."""

from functools import lru_cache

import numpy as np

from ..gps import BITS_PER_SUBFRAME, Ephemeris, IonoParams, SECONDS_PER_WEEK, SUBFRAME_S, UtcParams, subframe_bits

SUBFRAMES_PER_WEEK = int(SECONDS_PER_WEEK / SUBFRAME_S)


class NavStream:
    """Data bits of one satellite as +/-1 (logic 0 -> +1), indexed by bit count since the GPS epoch."""

    def __init__(self, ephemeris: Ephemeris, iono: IonoParams, utc: UtcParams, almanac: dict[int, Ephemeris]):
        self._eph, self._iono, self._utc, self._almanac = ephemeris, iono, utc, almanac
        self._subframe = lru_cache(maxsize=8)(self._build)

    def _build(self, subframe_count: int) -> np.ndarray:
        bits = subframe_bits(subframe_count % SUBFRAMES_PER_WEEK, self._eph, self._iono, self._utc, self._almanac)
        return (1 - 2 * bits.astype(np.int8)).astype(np.int8)

    def bits(self, first_bit: int, n_bits: int) -> np.ndarray:
        first_sf, last_sf = first_bit // BITS_PER_SUBFRAME, (first_bit + n_bits - 1) // BITS_PER_SUBFRAME
        stream = np.concatenate([self._subframe(k) for k in range(first_sf, last_sf + 1)])
        start = first_bit - first_sf * BITS_PER_SUBFRAME
        return stream[start:start + n_bits]

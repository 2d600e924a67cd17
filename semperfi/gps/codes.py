"""C/A Gold codes (IS-GPS-200 20.3.2.3): G1 xor a delayed G2, the delay given per PRN by its two G2 taps."""

from functools import lru_cache

import numpy as np

from .constants import CA_CODE_LENGTH_CHIPS

# G2 phase-selector taps (1-based register stages) for PRN 1..32, IS-GPS-200 Table 3-Ia.
G2_TAPS = (
    (2, 6), (3, 7), (4, 8), (5, 9), (1, 9), (2, 10), (1, 8), (2, 9), (3, 10), (2, 3),
    (3, 4), (5, 6), (6, 7), (7, 8), (8, 9), (9, 10), (1, 4), (2, 5), (3, 6), (4, 7),
    (5, 8), (6, 9), (1, 3), (4, 6), (5, 7), (6, 8), (7, 9), (8, 10), (1, 6), (2, 7),
    (3, 8), (4, 9),
)
PRNS = tuple(range(1, len(G2_TAPS) + 1))


def _register_sequence(feedback_stages: tuple[int, ...], output_stages: tuple[int, ...]) -> np.ndarray:
    """1023 output bits (0/1) of a 10-stage LFSR loaded with all ones."""
    reg = [1] * 10
    out = np.empty(CA_CODE_LENGTH_CHIPS, dtype=np.int8)
    for i in range(CA_CODE_LENGTH_CHIPS):
        bit = 0
        for s in output_stages:
            bit ^= reg[s - 1]
        out[i] = bit
        fb = 0
        for s in feedback_stages:
            fb ^= reg[s - 1]
        reg = [fb] + reg[:-1]
    return out


@lru_cache(maxsize=None)
def ca_code_bits(prn: int) -> np.ndarray:
    """The 1023 chips of PRN's C/A code as 0/1 (read-only)."""
    if prn not in PRNS:
        raise ValueError(f"PRN {prn} is not a GPS C/A code (1-{len(PRNS)})")
    g1 = _register_sequence((3, 10), (10,))
    g2 = _register_sequence((2, 3, 6, 8, 9, 10), G2_TAPS[prn - 1])
    code = g1 ^ g2
    code.setflags(write=False)
    return code


@lru_cache(maxsize=None)
def ca_code(prn: int) -> np.ndarray:
    """The 1023 chips of PRN's C/A code as +/-1 (logic 0 -> +1), read-only."""
    code = (1 - 2 * ca_code_bits(prn)).astype(np.int8)
    code.setflags(write=False)
    return code


# G2 delays (chips) of Gold codes of the C/A family that no system transmits on L1 (GPS PRNs 1-63, SBAS 120-158,
# QZSS 193-202 use others, and neither these nor 1023 minus them): what a search finds with one is not a satellite.
UNUSED_G2_DELAYS = (300, 400, 600)


@lru_cache(maxsize=None)
def gold_code(g2_delay_chips: int) -> np.ndarray:
    """G1 xor G2 delayed by g2_delay_chips, as +/-1 (read-only): PRN 1 is delay 5 (IS-GPS-200 Table 3-Ia)."""
    g1 = _register_sequence((3, 10), (10,))
    g2 = _register_sequence((2, 3, 6, 8, 9, 10), (10,))
    code = (1 - 2 * (g1 ^ np.roll(g2, g2_delay_chips))).astype(np.int8)
    code.setflags(write=False)
    return code


def first_chips_octal(prn: int, n_chips: int = 10) -> str:
    """The first chips of a code as the octal number IS-GPS-200 Table 3-Ia lists (logic 1 = 1)."""
    value = 0
    for b in ca_code_bits(prn)[:n_chips]:
        value = (value << 1) | int(b)
    return format(value, "o")


def sampled_code(prn: int, fs_hz: float, n_samples: int, code_phase_chips: float = 0.0,
                 chip_rate_hz: float = 1.023e6) -> np.ndarray:
    """The +/-1 code sampled at fs, starting code_phase_chips into the code (the local replica)."""
    idx = np.floor(code_phase_chips + np.arange(n_samples) * (chip_rate_hz / fs_hz)).astype(np.int64)
    return ca_code(prn)[idx % CA_CODE_LENGTH_CHIPS]


def chips_offset(a: float, b: float) -> float:
    """Code phase a minus b, wrapped to (-511.5, 511.5] chips."""
    return (a - b + CA_CODE_LENGTH_CHIPS / 2) % CA_CODE_LENGTH_CHIPS - CA_CODE_LENGTH_CHIPS / 2


def chips_apart(a: float, b: float) -> float:
    return abs(chips_offset(a, b))

"""The LNAV navigation message of IS-GPS-200 section 20.3: subframe encoding and decoding, parity, field tables.

Bits are numpy uint8 arrays of 0/1, most significant bit first as transmitted. One table per subframe or page
lists every field as (name, scale, signed, parts), where a part is (word 3-10, first bit 1-24, length) and a split
field has several parts, MSB part first. Encoding and decoding both read the same table, so they cannot drift apart.
Scales are physical units per LSB; angles are radians in the tables and semicircles on the air (rad = sc * GPS_PI).
"""

import dataclasses
import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .constants import GPS_PI
from .ephemeris import Ephemeris, IonoParams, UtcParams

PREAMBLE = np.array([1, 0, 0, 0, 1, 0, 1, 1], dtype=np.uint8)
SUBFRAMES_PER_WEEK = 100800      # 604800 s / 6 s: the HOW's TOW count runs 0..100799
DATA_ID_LNAV = 0b01              # data ID of every page of subframes 4 and 5

SubframeData = np.ndarray        # the 192 source bits of words 3-10, 24 a word (word 10's last two are solved as t)

# ---------------------------------------------------------------------------------------------------- parity

# IS-GPS-200 Table 20-XIV: D25..D30 = (D29* or D30* of the previous word) xor the source bits d_i listed.
_PARITY_EQUATIONS = (
    (29, (1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23)),
    (30, (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24)),
    (29, (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22)),
    (30, (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23)),
    (30, (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24)),
    (29, (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24)),
)
_PARITY_MATRIX = np.array([[int(i in taps) for i in range(1, 25)] for _, taps in _PARITY_EQUATIONS], dtype=np.int64)
_STARTS_FROM_D29 = np.array([star == 29 for star, _ in _PARITY_EQUATIONS])


def _parity_bits(source24: np.ndarray, d29_prev: int, d30_prev: int) -> np.ndarray:
    """D25..D30 of a word from its 24 source bits d1..d24 and the previous word's last two bits."""
    start = np.where(_STARTS_FROM_D29, int(d29_prev), int(d30_prev))
    return ((_PARITY_MATRIX @ source24.astype(np.int64) + start) & 1).astype(np.uint8)


def _encode_word(source24: np.ndarray, d29_prev: int, d30_prev: int) -> np.ndarray:
    """30 transmitted bits: data complemented when D30* = 1, then parity."""
    data = source24.astype(np.uint8) ^ np.uint8(d30_prev)
    return np.concatenate([data, _parity_bits(source24, d29_prev, d30_prev)])


def _solve_t(source24: np.ndarray, d29_prev: int, d30_prev: int) -> np.ndarray:
    """Set bits 23-24 (the non-information bits t) so the word ends in D29 = D30 = 0 (IS-GPS-200 20.3.5.2)."""
    for t in ((0, 0), (0, 1), (1, 0), (1, 1)):
        candidate = source24.astype(np.uint8).copy()
        candidate[22:24] = t
        if not _parity_bits(candidate, d29_prev, d30_prev)[4:].any():
            return candidate
    raise AssertionError("unreachable: D29 depends on d24 and D30 on d23, so one choice of t always works")


def check_parity(word30_bits, d29_prev: int, d30_prev: int) -> tuple[bool, np.ndarray]:
    """Check one received 30-bit word; returns (parity ok, its 24 source data bits d1..d24)."""
    word = np.asarray(word30_bits, dtype=np.uint8)
    data = word[:24] ^ np.uint8(d30_prev)
    return bool(np.array_equal(_parity_bits(data, d29_prev, d30_prev), word[24:30])), data


# ---------------------------------------------------------------------------------------------------- fields

def _to_bits(value: int, n: int) -> np.ndarray:
    return np.array([(value >> (n - 1 - i)) & 1 for i in range(n)], dtype=np.uint8)


def _from_bits(bits) -> int:
    value = 0
    for b in bits:
        value = (value << 1) | int(b)
    return value


@dataclass(frozen=True)
class Field:
    """One message field: value = integer * scale (an int scale gives int values); parts MSB first."""
    name: str
    scale: float
    signed: bool
    parts: tuple[tuple[int, int, int], ...]   # (word 3-10, first bit 1-24, length)

    @property
    def length(self) -> int:
        return sum(n for _, _, n in self.parts)

    def to_int(self, value) -> int:
        """The field's n-bit pattern for value, rounded to the nearest LSB; ValueError if it does not fit."""
        x = float(value) / self.scale
        n = self.length
        low, high = (-(1 << (n - 1)), (1 << (n - 1)) - 1) if self.signed else (0, (1 << n) - 1)
        if not math.isfinite(x) or not low <= round(x) <= high:
            kind = "signed" if self.signed else "unsigned"
            raise ValueError(f"LNAV field {self.name} = {value!r} does not fit {n} {kind} bits of LSB {self.scale!r}")
        return round(x) & ((1 << n) - 1)

    def from_int(self, raw: int):
        if self.signed and raw >> (self.length - 1):
            raw -= 1 << self.length
        return raw * self.scale


Layout = tuple[Field, ...]


def _f(name: str, scale: float, signed: bool, *parts: tuple[int, int, int]) -> Field:
    return Field(name, scale, signed, tuple(parts))


def _at(offset: int, n: int) -> tuple[int, int, int]:
    """The part starting `offset` bits into the 192-bit payload (for the regular arrays of page 25)."""
    return 3 + offset // 24, offset % 24 + 1, n


_SC = GPS_PI   # radians per semicircle

SUBFRAME_1: Layout = (
    _f("week_mod_1024", 1, False, (3, 1, 10)),
    _f("code_on_l2", 1, False, (3, 11, 2)),
    _f("ura_index", 1, False, (3, 13, 4)),
    _f("health", 1, False, (3, 17, 6)),
    _f("iodc", 1, False, (3, 23, 2), (8, 1, 8)),
    _f("l2p_data_flag", 1, False, (4, 1, 1)),
    _f("tgd_s", 2.0 ** -31, True, (7, 17, 8)),
    _f("toc_s", 2.0 ** 4, False, (8, 9, 16)),
    _f("af2_s_s2", 2.0 ** -55, True, (9, 1, 8)),
    _f("af1_s_s", 2.0 ** -43, True, (9, 9, 16)),
    _f("af0_s", 2.0 ** -31, True, (10, 1, 22)),
)
SUBFRAME_2: Layout = (
    _f("iode", 1, False, (3, 1, 8)),
    _f("crs_m", 2.0 ** -5, True, (3, 9, 16)),
    _f("delta_n_rad_s", 2.0 ** -43 * _SC, True, (4, 1, 16)),
    _f("m0_rad", 2.0 ** -31 * _SC, True, (4, 17, 8), (5, 1, 24)),
    _f("cuc_rad", 2.0 ** -29, True, (6, 1, 16)),
    _f("e", 2.0 ** -33, False, (6, 17, 8), (7, 1, 24)),
    _f("cus_rad", 2.0 ** -29, True, (8, 1, 16)),
    _f("sqrt_a_sqrt_m", 2.0 ** -19, False, (8, 17, 8), (9, 1, 24)),
    _f("toe_s", 2.0 ** 4, False, (10, 1, 16)),
    _f("fit_interval_flag", 1, False, (10, 17, 1)),
    _f("aodo_s", 900, False, (10, 18, 5)),
)
SUBFRAME_3: Layout = (
    _f("cic_rad", 2.0 ** -29, True, (3, 1, 16)),
    _f("omega0_rad", 2.0 ** -31 * _SC, True, (3, 17, 8), (4, 1, 24)),
    _f("cis_rad", 2.0 ** -29, True, (5, 1, 16)),
    _f("i0_rad", 2.0 ** -31 * _SC, True, (5, 17, 8), (6, 1, 24)),
    _f("crc_m", 2.0 ** -5, True, (7, 1, 16)),
    _f("omega_rad", 2.0 ** -31 * _SC, True, (7, 17, 8), (8, 1, 24)),
    _f("omega_dot_rad_s", 2.0 ** -43 * _SC, True, (9, 1, 24)),
    _f("iode", 1, False, (10, 1, 8)),
    _f("idot_rad_s", 2.0 ** -43 * _SC, True, (10, 9, 14)),
)
PAGE_HEADER: Layout = (_f("data_id", 1, False, (3, 1, 2)), _f("sv_id", 1, False, (3, 3, 6)))
ALMANAC: Layout = PAGE_HEADER + (
    _f("e", 2.0 ** -21, False, (3, 9, 16)),
    _f("toa_s", 2 ** 12, False, (4, 1, 8)),
    _f("delta_i_rad", 2.0 ** -19 * _SC, True, (4, 9, 16)),      # i0 - 0.30 semicircles
    _f("omega_dot_rad_s", 2.0 ** -38 * _SC, True, (5, 1, 16)),
    _f("health", 1, False, (5, 17, 8)),
    _f("sqrt_a_sqrt_m", 2.0 ** -11, False, (6, 1, 24)),
    _f("omega0_rad", 2.0 ** -23 * _SC, True, (7, 1, 24)),
    _f("omega_rad", 2.0 ** -23 * _SC, True, (8, 1, 24)),
    _f("m0_rad", 2.0 ** -23 * _SC, True, (9, 1, 24)),
    _f("af0_s", 2.0 ** -20, True, (10, 1, 8), (10, 20, 3)),
    _f("af1_s_s", 2.0 ** -38, True, (10, 9, 11)),
)
IONO_UTC: Layout = PAGE_HEADER + (                                # subframe 4 page 18
    _f("alpha0", 2.0 ** -30, True, (3, 9, 8)),                    # s, s/sc, s/sc^2, s/sc^3
    _f("alpha1", 2.0 ** -27, True, (3, 17, 8)),
    _f("alpha2", 2.0 ** -24, True, (4, 1, 8)),
    _f("alpha3", 2.0 ** -24, True, (4, 9, 8)),
    _f("beta0", 2.0 ** 11, True, (4, 17, 8)),
    _f("beta1", 2.0 ** 14, True, (5, 1, 8)),
    _f("beta2", 2.0 ** 16, True, (5, 9, 8)),
    _f("beta3", 2.0 ** 16, True, (5, 17, 8)),
    _f("a1_s_s", 2.0 ** -50, True, (6, 1, 24)),
    _f("a0_s", 2.0 ** -30, True, (7, 1, 24), (8, 1, 8)),
    _f("tot_s", 2 ** 12, False, (8, 9, 8)),
    _f("wnt", 1, False, (8, 17, 8)),
    _f("delta_t_ls_s", 1, True, (9, 1, 8)),
    _f("wn_lsf", 1, False, (9, 9, 8)),
    _f("dn", 1, False, (9, 17, 8)),
    _f("delta_t_lsf_s", 1, True, (10, 1, 8)),
)
SUBFRAME_5_HEALTH: Layout = PAGE_HEADER + (                      # subframe 5 page 25: 6-bit health of SV 1-24
    _f("toa_s", 2 ** 12, False, (3, 9, 8)),
    _f("wna", 1, False, (3, 17, 8)),
) + tuple(_f(f"health_prn{prn:02d}", 1, False, _at(24 + 6 * (prn - 1), 6)) for prn in range(1, 25))
SUBFRAME_4_CONFIG_HEALTH: Layout = PAGE_HEADER + tuple(          # subframe 4 page 25: A-S/config of 1-32, health 25-32
    _f(f"config_prn{prn:02d}", 1, False, _at(8 + 4 * (prn - 1), 4)) for prn in range(1, 33)
) + tuple(_f(f"health_prn{prn:02d}", 1, False, _at(138 + 6 * (prn - 25), 6)) for prn in range(25, 33))

# IS-GPS-200 Table 20-V: the SV ID each page of subframe 4 carries (subframe 5: page 1-24 -> PRN, page 25 -> 51).
SUBFRAME_4_SV_ID = dict(enumerate(
    (57, 25, 26, 27, 28, 57, 29, 30, 31, 32, 57, 62, 52, 53, 54, 57, 55, 56, 58, 59, 57, 60, 61, 62, 63), start=1))
_SUBFRAME_5_SV_ID = {**{page: page for page in range(1, 25)}, 25: 51}
# SV IDs that name one page; 57 and 62 recur and a dummy almanac has SV ID 0, so those pages come from the TOW.
_PAGE_OF_SV_ID = {
    4: {sv: page for page, sv in SUBFRAME_4_SV_ID.items() if list(SUBFRAME_4_SV_ID.values()).count(sv) == 1},
    5: {sv: page for page, sv in _SUBFRAME_5_SV_ID.items()},
}
_DUMMY_FILLER = np.tile(np.array([1, 0], dtype=np.uint8), 96)   # a dummy SV's almanac: alternating ones and zeros


def page_sv_id(subframe_id: int, page: int) -> int:
    """The SV ID IS-GPS-200 Table 20-V assigns to a page of subframe 4 or 5."""
    return SUBFRAME_4_SV_ID[page] if subframe_id == 4 else _SUBFRAME_5_SV_ID[page]


def almanac_prn(subframe_id: int, page: int) -> int | None:
    """The PRN whose almanac a page carries, or None if it carries something else."""
    sv_id = page_sv_id(subframe_id, page) if subframe_id in (4, 5) else 0
    return sv_id if 1 <= sv_id <= 32 else None


def page_layout(subframe_id: int, page: int = 0) -> Layout:
    """The field table of subframe 1-3, or of a page 1-25 of subframe 4 or 5."""
    if subframe_id in (1, 2, 3):
        return (SUBFRAME_1, SUBFRAME_2, SUBFRAME_3)[subframe_id - 1]
    if almanac_prn(subframe_id, page) is not None:
        return ALMANAC
    if (subframe_id, page) == (4, 18):
        return IONO_UTC
    if page == 25:
        return SUBFRAME_4_CONFIG_HEALTH if subframe_id == 4 else SUBFRAME_5_HEALTH
    return PAGE_HEADER      # reserved, NMCT and special-message pages: header, then zeros


def pack(layout: Layout, values: Mapping[str, float], base: np.ndarray | None = None) -> SubframeData:
    """Write the fields of layout, taken from values, into a 192-bit payload (zeros, or a copy of base)."""
    data = np.zeros(192, dtype=np.uint8) if base is None else np.array(base, dtype=np.uint8)
    for field in layout:
        bits, at = _to_bits(field.to_int(values[field.name]), field.length), 0
        for word, first, n in field.parts:
            start = (word - 3) * 24 + first - 1
            data[start:start + n] = bits[at:at + n]
            at += n
    return data


def unpack(layout: Layout, data: SubframeData) -> dict:
    """Read the fields of layout from a 192-bit payload, in physical units."""
    out = {}
    for field in layout:
        bits = [data[(word - 3) * 24 + first - 1:(word - 3) * 24 + first - 1 + n] for word, first, n in field.parts]
        out[field.name] = field.from_int(_from_bits(np.concatenate(bits)))
    return out


# ---------------------------------------------------------------------------------------------------- subframes

def encode_subframe(subframe_id: int, tow_count_next: int, data: SubframeData, alert: int = 0, anti_spoof: int = 0,
                    tlm_message: int = 0, integrity: int = 0) -> np.ndarray:
    """300 transmitted bits: TLM, HOW, then words 3-10 from data, parity applied.

    tow_count_next is the truncated TOW count (units of 6 s) of the next subframe's start. The t bits of words 2
    and 10 make both end in 00, so the subframe starts from D29* = D30* = 0 and stands on its own.
    """
    if subframe_id not in range(1, 6) or tow_count_next not in range(SUBFRAMES_PER_WEEK) \
            or tlm_message not in range(1 << 14) or not {alert, anti_spoof, integrity} <= {0, 1}:
        raise ValueError(f"bad TLM/HOW: subframe {subframe_id}, TOW count {tow_count_next}, TLM {tlm_message}, "
                         f"flags {alert}/{anti_spoof}/{integrity}")
    data = np.asarray(data, dtype=np.uint8)
    if data.shape != (192,):
        raise ValueError(f"subframe data must be 192 bits (words 3-10), got shape {data.shape}")
    tlm = np.concatenate([PREAMBLE, _to_bits(tlm_message, 14), [integrity, 0]])
    how = np.concatenate([_to_bits(tow_count_next, 17), [alert, anti_spoof], _to_bits(subframe_id, 3), [0, 0]])
    bits = np.empty(300, dtype=np.uint8)
    d29, d30 = 0, 0
    for i, source in enumerate([tlm, how, *data.reshape(8, 24)]):
        if i in (1, 9):
            source = _solve_t(source, d29, d30)
        word = _encode_word(source, d29, d30)
        bits[30 * i:30 * i + 30] = word
        d29, d30 = int(word[28]), int(word[29])
    return bits


@dataclass(frozen=True, eq=False)
class DecodedSubframe:
    """What one received subframe says; data_bits are d1..d24 of words 1-10, parity removed and un-complemented."""
    subframe_id: int
    tow_count_next: int       # truncated TOW count (6 s units) of the next subframe's start
    alert: int
    anti_spoof: int
    page: int                 # 1-25 for subframes 4 and 5 (from the SV ID where it names one page, else the TOW)
    sv_id: int                # SV ID of subframes 4 and 5 (0: dummy almanac); 0 for subframes 1-3
    parity_errors: int        # number of words failing parity
    data_bits: np.ndarray     # 240 bits
    tlm_message: int = 0
    integrity: int = 0

    @property
    def payload(self) -> SubframeData:
        """The 192 data bits of words 3-10, as pack/unpack take them."""
        return self.data_bits[48:]


def decode_subframe(bits300, d29_prev: int = 0, d30_prev: int = 0) -> DecodedSubframe:
    """Decode 300 received bits aligned on a preamble; d29_prev, d30_prev are the last two bits before them."""
    bits = np.asarray(bits300, dtype=np.uint8)
    if bits.shape != (300,):
        raise ValueError(f"a subframe is 300 bits, got shape {bits.shape}")
    data = np.empty(240, dtype=np.uint8)
    errors = 0
    for i in range(10):
        word = bits[30 * i:30 * i + 30]
        ok, data[24 * i:24 * i + 24] = check_parity(word, d29_prev, d30_prev)
        errors += not ok
        d29_prev, d30_prev = int(word[28]), int(word[29])
    data.setflags(write=False)
    subframe_id, tow_count_next = _from_bits(data[43:46]), _from_bits(data[24:41])
    sv_id = page = 0
    if subframe_id in (4, 5):
        sv_id = _from_bits(data[50:56])
        page = _PAGE_OF_SV_ID[subframe_id].get(sv_id) or \
            ((tow_count_next - 1) % SUBFRAMES_PER_WEEK // 5) % 25 + 1
    return DecodedSubframe(subframe_id=subframe_id, tow_count_next=tow_count_next, alert=int(data[41]),
                           anti_spoof=int(data[42]), page=page, sv_id=sv_id, parity_errors=errors, data_bits=data,
                           tlm_message=_from_bits(data[8:22]), integrity=int(data[22]))


def page_fields(subframe: DecodedSubframe) -> dict:
    """All fields of a decoded subframe or page, in physical units (a dummy almanac gives just its header)."""
    layout = page_layout(subframe.subframe_id, subframe.page)
    if layout is ALMANAC and subframe.sv_id == 0:
        layout = PAGE_HEADER
    return unpack(layout, subframe.payload)


# ---------------------------------------------------------------------------------------------------- contents

def ephemeris_values(eph: Ephemeris) -> dict:
    """The fields of subframes 1-3 for an ephemeris (AODO is not modelled: 0)."""
    return {**dataclasses.asdict(eph), "week_mod_1024": eph.week % 1024, "aodo_s": 0}


def almanac_values(eph: Ephemeris) -> dict:
    """The almanac page fields for a satellite, its almanac taken from its ephemeris (toa = toe, quantized)."""
    nav_data_health = 0b111 if eph.health & 0x20 else 0    # 3-bit NAV data health: all bad / all good
    return {"data_id": DATA_ID_LNAV, "sv_id": eph.prn, "e": eph.e, "toa_s": eph.toe_s,
            "delta_i_rad": eph.i0_rad - 0.30 * GPS_PI, "omega_dot_rad_s": eph.omega_dot_rad_s,
            "health": nav_data_health << 5 | eph.health & 0x1F, "sqrt_a_sqrt_m": eph.sqrt_a_sqrt_m,
            "omega0_rad": eph.omega0_rad, "omega_rad": eph.omega_rad, "m0_rad": eph.m0_rad,
            "af0_s": eph.af0_s, "af1_s_s": eph.af1_s_s}


def iono_utc_values(iono: IonoParams, utc: UtcParams) -> dict:
    return {**{f"alpha{i}": a for i, a in enumerate(iono.alpha)}, **{f"beta{i}": b for i, b in enumerate(iono.beta)},
            **dataclasses.asdict(utc)}


def _page_payload(subframe_id: int, page: int, iono: IonoParams, utc: UtcParams,
                  almanac_source: Mapping[int, Ephemeris]) -> SubframeData:
    values = {"data_id": DATA_ID_LNAV, "sv_id": page_sv_id(subframe_id, page)}
    prn = almanac_prn(subframe_id, page)
    if prn is not None:
        if prn not in almanac_source:     # dummy SV: SV ID 0, the rest filler
            return pack(PAGE_HEADER, {"data_id": DATA_ID_LNAV, "sv_id": 0}, base=_DUMMY_FILLER)
        values.update(almanac_values(almanac_source[prn]))
    elif (subframe_id, page) == (4, 18):
        values.update(iono_utc_values(iono, utc))
    elif page == 25:
        # Health as subframe 1 codes it, from the almanac source; 0 (healthy, or no claim) for the rest.
        # A-S/configuration codes of subframe 4 are left 0.
        values.update({f"health_prn{prn:02d}": almanac_source[prn].health if prn in almanac_source else 0
                       for prn in range(1, 33)})
        values.update({f"config_prn{prn:02d}": 0 for prn in range(1, 33)})
        reference = almanac_source[min(almanac_source)] if almanac_source else None
        values["toa_s"] = reference.toe_s if reference else 0
        values["wna"] = reference.week % 256 if reference else 0
    return pack(page_layout(subframe_id, page), values)


def subframe_bits(k: int, ephemeris: Ephemeris, iono: IonoParams, utc: UtcParams,
                  almanac_source: Mapping[int, Ephemeris], *, alert: int = 0, anti_spoof: int = 0,
                  tlm_message: int = 0, integrity: int = 0) -> np.ndarray:
    """The 300 bits a satellite sends as subframe number k of the week (it starts at SV time 6 k s of week).

    Subframe id = k % 5 + 1; subframes 4 and 5 carry page (k // 5) % 25 + 1. almanac_source (prn -> Ephemeris, may
    be empty) fills the almanac pages; a PRN missing from it gets a dummy almanac page.
    """
    k %= SUBFRAMES_PER_WEEK
    subframe_id = k % 5 + 1
    if subframe_id <= 3:
        data = pack(page_layout(subframe_id), ephemeris_values(ephemeris))
    else:
        data = _page_payload(subframe_id, (k // 5) % 25 + 1, iono, utc, almanac_source)
    return encode_subframe(subframe_id, (k + 1) % SUBFRAMES_PER_WEEK, data, alert=alert, anti_spoof=anti_spoof,
                           tlm_message=tlm_message, integrity=integrity)


def full_week(week_mod_1024: int, full_week_hint: int | None = None) -> int:
    """The full GPS week of a broadcast 10-bit week number: the one nearest full_week_hint, or without a hint the one
    in the era that began 2019-04-07 (week 2048)."""
    wn = int(week_mod_1024)
    return 2048 + wn if full_week_hint is None else full_week_hint + (wn - full_week_hint + 512) % 1024 - 512


def week_of_subframe1(sf: DecodedSubframe, full_week_hint: int | None = None) -> int:
    """The full GPS week a subframe 1 with good parity says (ValueError for any other subframe)."""
    if sf.subframe_id != 1 or sf.parity_errors:
        raise ValueError(f"the week is in subframe 1 with good parity, not subframe {sf.subframe_id} "
                         f"with {sf.parity_errors} parity errors")
    return full_week(unpack(page_layout(1), sf.payload)["week_mod_1024"], full_week_hint)


def ephemeris_from_subframes(sf1: DecodedSubframe, sf2: DecodedSubframe, sf3: DecodedSubframe, prn: int,
                             full_week_hint: int | None = None) -> Ephemeris:
    """The ephemeris that subframes 1, 2, 3 of one upload carry (IODE of 2 and 3 = IODC mod 256).

    The 10-bit week number becomes a full week as full_week resolves it.
    """
    for n, sf in enumerate((sf1, sf2, sf3), start=1):
        if sf.subframe_id != n or sf.parity_errors:
            raise ValueError(f"expected subframe {n} with good parity, got subframe {sf.subframe_id} "
                             f"with {sf.parity_errors} parity errors")
    clock, orbit2, orbit3 = (unpack(page_layout(n), sf.payload) for n, sf in enumerate((sf1, sf2, sf3), start=1))
    if not orbit2["iode"] == orbit3["iode"] == clock["iodc"] % 256:
        raise ValueError(f"subframes of different uploads: IODC {clock['iodc']}, IODE {orbit2['iode']} and "
                         f"{orbit3['iode']}")
    week = full_week(clock["week_mod_1024"], full_week_hint)
    names = {f.name for f in dataclasses.fields(Ephemeris)}
    values = {name: value for name, value in {**clock, **orbit2, **orbit3}.items() if name in names}
    return Ephemeris(prn=prn, week=week, **values)


def iono_utc_from_subframe(sf: DecodedSubframe) -> tuple[IonoParams, UtcParams]:
    """Klobuchar and GPS-UTC parameters from subframe 4 page 18 (SV ID 56)."""
    if sf.subframe_id != 4 or sf.sv_id != 56 or sf.parity_errors:
        raise ValueError(f"expected subframe 4 page 18 with good parity, got subframe {sf.subframe_id} SV ID "
                         f"{sf.sv_id} with {sf.parity_errors} parity errors")
    v = unpack(IONO_UTC, sf.payload)
    iono = IonoParams(alpha=tuple(v[f"alpha{i}"] for i in range(4)), beta=tuple(v[f"beta{i}"] for i in range(4)))
    return iono, UtcParams(**{f.name: v[f.name] for f in dataclasses.fields(UtcParams)})


def quantize_ephemeris(eph: Ephemeris) -> Ephemeris:
    """What a receiver decodes from the broadcast of eph: subframes 1-3 encoded, then decoded."""
    decoded = [decode_subframe(encode_subframe(n, n, pack(page_layout(n), ephemeris_values(eph)))) for n in (1, 2, 3)]
    return ephemeris_from_subframes(*decoded, prn=eph.prn, full_week_hint=eph.week)

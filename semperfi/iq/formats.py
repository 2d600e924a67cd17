"""Sample formats of IQ files, named as GNSS-SDR's file source names them (`item_type`) and as SigMF's core
datatypes name them (`ci16_le`, `ri8`, `cu8`, ...).

Complex formats store one sample as I then Q; real formats store one real sample of a signal at an IF (GNSS-SDR's
`byte`/`short`, PocketSDR's "I" sampling). Packed formats hold several 2- or 4-bit values per byte, as low-bit front
ends (MAX2769-class) write them: `real2`/`iq2` are GNSS-SDR's Two_Bit_Packed_File_Signal_Source (two's complement
value v -> 2v+1, i.e. -3 -1 1 3; the first value in the byte's lowest bits), `real2sm`/`iq2sm` sign-magnitude (sign
bit then magnitude bit, 1 = negative; -> +-1, +-3; the first value in the highest bits, the order a serial
sign/magnitude interface shifts them in), `real4`/`iq4` 4-bit two's complement nibbles (v -> 2v+1, high nibble
first; a complex sample is one byte, I in the high nibble). Decoding gives complex64 with the raw values (no
normalisation, as GNSS-SDR does; unsigned integers are centred on their mid-scale, as rtl_sdr's uint8 are). A real
sample decodes to x + 0j at its IF: correlating it with a complex carrier at +IF picks the upper of its two spectral
images, as SoftGNSS does, so the chain needs no other change (the image at -IF is 2 IF away from any Doppler
searched).
"""

from __future__ import annotations

import functools
import math
import numbers
from dataclasses import dataclass, replace

import numpy as np


MAX_READ_BYTES = 1 << 30   # one request never asks for more than this (a hostile --fs cannot exhaust memory)


@dataclass(frozen=True)
class SampleFormat:
    """How one sample is laid out on disk."""
    name: str                 # GNSS-SDR item_type where it has one ('ibyte', 'byte', ...), else the SigMF datatype
    item_dtype: np.dtype      # numpy dtype of one stored item (an I, a Q, a real value, or a whole complex)
    bytes_per_sample: int     # bytes of one sample (I and Q together for complex formats)
    sigmf_datatype: str       # SigMF core:datatype
    is_complex: bool = True   # False: real samples at an IF
    iq_swapped: bool = False  # the front end stores Q before I (a spectrally inverted signal)
    bits: int = 0             # packed formats: bits per value (2 or 4), several values per byte; 0 = whole items
    sign_magnitude: bool = False   # packed values are sign|magnitude rather than two's complement
    msb_first: bool = False   # packed: the first value sits in the byte's highest bits

    @property
    def unswapped(self) -> SampleFormat:
        return replace(self, iq_swapped=False)

    @property
    def samples_per_block(self) -> int:
        """Samples in the smallest whole-byte unit: 1, or 2-4 for packed formats."""
        return 8 // (self.bits * (2 if self.is_complex else 1)) if self.bits else 1

    @property
    def block_bytes(self) -> int:
        """Bytes of that unit (one sample's bytes; one byte for packed formats)."""
        return 1 if self.bits else self.bytes_per_sample

    @property
    def items_per_block(self) -> int:
        """Stored items per block: 2 for interleaved integers (I, Q), 1 for complex floats, real and packed."""
        return self.block_bytes // self.item_dtype.itemsize

    @property
    def is_integer(self) -> bool:
        return self.item_dtype.kind in "iu"

    @property
    def offset(self) -> float:
        """Mid-scale of an unsigned integer format (127.5 for uint8), subtracted on decoding; 0 otherwise."""
        if self.item_dtype.kind != "u":
            return 0.0
        return (int(np.iinfo(self.item_dtype).max) + 1) / 2 - 0.5


def _sigmf_format(datatype: str, name: str | None = None) -> SampleFormat:
    """The format of a SigMF core:datatype such as 'ci16_le', 'ri8', 'cf32_be', 'cu8'."""
    kind, body = datatype[0], datatype[1:]
    base, _, endian = body.partition("_")
    code = {"i": "i", "u": "u", "f": "f"}[base[0]]
    size = int(base[1:]) // 8
    item = np.dtype(("<" if endian != "be" else ">") + code + str(size)) if size > 1 else np.dtype(code + "1")
    if kind == "c" and code == "f":   # a complex float is one numpy item
        item = np.dtype(item.byteorder.replace("=", "<") + "c" + str(2 * size))
        return SampleFormat(name or datatype, item, 2 * size, datatype)
    return SampleFormat(name or datatype, item, (2 if kind == "c" else 1) * size, datatype, is_complex=kind == "c")


# GNSS-SDR's item types, then every SigMF core datatype we can decode (the complex ones first).
IBYTE = _sigmf_format("ci8", "ibyte")
ISHORT = _sigmf_format("ci16_le", "ishort")
GR_COMPLEX = _sigmf_format("cf32_le", "gr_complex")
BYTE = _sigmf_format("ri8", "byte")
SHORT = _sigmf_format("ri16_le", "short")
FLOAT = _sigmf_format("rf32_le", "float")
_SIGMF_ONLY = tuple(_sigmf_format(d) for d in (
    "cu8", "ci16_be", "cu16_le", "cu16_be", "ci32_le", "ci32_be", "cf32_be", "cf64_le", "cf64_be",
    "ru8", "ri16_be", "ru16_le", "ru16_be", "ri32_le", "ri32_be", "rf32_be", "rf64_le", "rf64_be"))

_U8 = np.dtype("u1")
PACKED = (SampleFormat("real2", _U8, 1, "", is_complex=False, bits=2),
          SampleFormat("iq2", _U8, 1, "", bits=2),
          SampleFormat("real2sm", _U8, 1, "", is_complex=False, bits=2, sign_magnitude=True, msb_first=True),
          SampleFormat("iq2sm", _U8, 1, "", bits=2, sign_magnitude=True, msb_first=True),
          SampleFormat("real4", _U8, 1, "", is_complex=False, bits=4, msb_first=True),
          SampleFormat("iq4", _U8, 1, "", bits=4, msb_first=True))

FORMATS: tuple[SampleFormat, ...] = (IBYTE, ISHORT, GR_COMPLEX, BYTE, SHORT, FLOAT) + _SIGMF_ONLY + PACKED
_ALIASES = {"cfloat": GR_COMPLEX, "cbyte": IBYTE, "cshort": ISHORT}
_BY_NAME = {f.name: f for f in FORMATS} | _ALIASES | {f.sigmf_datatype: f for f in FORMATS if f.sigmf_datatype}
_BY_SIGMF = {f.sigmf_datatype: f for f in FORMATS if f.sigmf_datatype}
FORMAT_NAMES: tuple[str, ...] = ("ibyte", "ishort", "gr_complex", "cfloat", "byte", "short", "float") + tuple(
    f.name for f in PACKED)
SIGMF_DATATYPES: tuple[str, ...] = tuple(_BY_SIGMF)


def format_by_name(name: str) -> SampleFormat:
    """The format GNSS-SDR calls `name` ('ibyte', 'ishort', 'gr_complex'/'cfloat', real 'byte', 'short', 'float')
    or a SigMF core datatype ('ci8', 'ri16_le', 'cu8', ...)."""
    key = name.strip().lower() if isinstance(name, str) else None
    if key not in _BY_NAME:
        raise ValueError(f"unknown sample format {_short(name)}; valid formats: {', '.join(FORMAT_NAMES)}, "
                         f"or a SigMF datatype ({', '.join(SIGMF_DATATYPES[:8])}, ...)")
    return _BY_NAME[key]


def format_by_sigmf_datatype(datatype: str) -> SampleFormat:
    """The format whose SigMF core:datatype is `datatype` ('ci8', 'ci16_le', 'cf32_le', 'ri8', 'cu8', ...)."""
    if not isinstance(datatype, str) or datatype not in _BY_SIGMF:
        raise ValueError(f"unsupported SigMF datatype {_short(datatype)}; supported: c|r + i8, u8, i16, u16, i32 "
                         "(_le/_be), f32, f64 (_le/_be)")
    return _BY_SIGMF[datatype]


def as_format(fmt: SampleFormat | str) -> SampleFormat:
    """Accept a SampleFormat or its name, so callers can pass a CLI string straight through."""
    if isinstance(fmt, SampleFormat):
        return fmt
    return format_by_name(fmt)


def with_iq_swap(fmt: SampleFormat | str) -> SampleFormat:
    """`fmt` with I and Q exchanged on disk (Q first), for front ends that deliver Q/I; complex formats only."""
    fmt = as_format(fmt)
    if not fmt.is_complex:
        raise ValueError(f"--iq-swap applies to complex samples; {fmt.name!r} holds real samples")
    return replace(fmt, iq_swapped=True)


def decode_items(items: np.ndarray, fmt: SampleFormat) -> np.ndarray:
    """Stored items (whole samples) -> a new complex64 array, raw values, not normalised.

    Complex formats give I + jQ (with `fmt.iq_swapped` the first stored value is Q: front ends that deliver Q
    first, i.e. a spectrally inverted signal); real formats give x + 0j.
    """
    items = np.asarray(items)
    if fmt.is_complex and not fmt.is_integer:
        out = np.array(items, dtype=np.complex64)   # a copy in native byte order, detached from any memmap
        if fmt.iq_swapped:
            out = out.view(np.float32).reshape(-1, 2)[:, ::-1].copy().view(np.complex64).ravel()
        return out
    if fmt.bits:
        values = _packed_table(fmt.bits, fmt.sign_magnitude, fmt.msb_first)[items.astype(np.uint8)].reshape(-1)
    else:
        values = items.astype(np.float32)
        if fmt.offset:
            values -= np.float32(fmt.offset)
    if not fmt.is_complex:
        out = np.zeros(values.size, dtype=np.complex64)
        out.real = values
        return out
    if fmt.iq_swapped:
        values = values.reshape(-1, 2)[:, ::-1].copy()
    # Interleaved I,Q as float32 *are* a complex64 array in memory: no further temporaries.
    return values.reshape(-1).view(np.complex64)


@functools.lru_cache(maxsize=None)
def _packed_table(bits: int, sign_magnitude: bool, msb_first: bool) -> np.ndarray:
    """byte -> its 8/bits values in stream order, float32 (a look-up table: one gather decodes a block)."""
    per_byte, mask = 8 // bits, (1 << bits) - 1
    shifts = [8 - bits * (i + 1) if msb_first else bits * i for i in range(per_byte)]
    fields = (np.arange(256)[:, None] >> np.array(shifts)) & mask
    if sign_magnitude:
        sign, magnitude = fields >> (bits - 1), fields & (mask >> 1)
        values = (1 - 2 * sign) * (2 * magnitude + 1)
    else:
        values = 2 * np.where(fields >= 1 << (bits - 1), fields - (1 << bits), fields) + 1
    return values.astype(np.float32)


def encode_samples(samples: np.ndarray, fmt: SampleFormat, scale: float = 1.0) -> tuple[np.ndarray, int]:
    """Complex samples -> (items in `fmt` ready to write, number of samples clipped).

    Integers: I and Q are multiplied by `scale`, rounded to nearest and clipped to the integer range; a sample
    counts as clipped when I or Q had to be. Floats: multiplied by `scale`; overflow to inf counts as clipped.
    Real formats keep the real part (the samples are a real signal at an IF).
    """
    if fmt.bits:
        raise ValueError(f"writing packed {fmt.bits}-bit samples ({fmt.name}) is not supported; write ibyte or byte")
    x = np.asarray(samples)
    if x.ndim != 1:
        raise ValueError(f"expected a 1-D array of complex samples, got shape {x.shape}")
    if not np.iscomplexobj(x):
        raise ValueError(f"expected complex samples, got dtype {x.dtype}")
    # Keep double precision when the caller has it; complex64 otherwise. A float view interleaves I, Q for free.
    work, part = (np.complex128, np.float64) if x.dtype.itemsize > 8 else (np.complex64, np.float32)
    iq = np.ascontiguousarray(x, dtype=work).view(part)
    if not np.isfinite(iq).all():
        raise ValueError("samples contain NaN or infinity; refusing to write them")
    per_sample = 2
    if fmt.iq_swapped:
        iq = iq.reshape(-1, 2)[:, ::-1].ravel()   # a copy, written Q first as the input was
    if not fmt.is_complex:
        iq, per_sample = iq[0::2].copy(), 1
    with np.errstate(over="ignore", invalid="ignore"):
        scaled = iq * scale if scale != 1.0 else iq.copy()
        if not fmt.is_integer:
            if fmt.is_complex:   # write I, Q as floats of half the complex item's size, same byte order
                part_dtype = fmt.item_dtype.byteorder.replace("=", "<") + "f" + str(fmt.item_dtype.itemsize // 2)
                out = scaled.astype(part_dtype).view(fmt.item_dtype)
            else:
                out = scaled.astype(fmt.item_dtype)
            return out, int((~np.isfinite(out)).sum())
        info = np.iinfo(fmt.item_dtype)
        np.rint(scaled, out=scaled)
        if fmt.offset:
            scaled += np.ceil(fmt.offset)   # 0 -> mid-scale (128 for uint8)
        over = (scaled < info.min) | (scaled > info.max)
        # I or Q over (a strided or: numpy's any over an axis of two takes ten times as long)
        clipped = int(np.count_nonzero(over[0::2] | over[1::2] if per_sample == 2 else over))
        np.clip(scaled, info.min, info.max, out=scaled)
        return scaled.astype(fmt.item_dtype), clipped


def _short(value) -> str:
    """repr() capped, so a hostile value (a 400-digit number from a sidecar) cannot flood an error line."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _finite_float(value, what: str) -> float:
    """A user-supplied number as float, or one clear ValueError (rejects bools, strings, NaN, inf)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{what} must be a number, got {_short(value)}")
    try:
        result = float(value)
    except (OverflowError, ValueError):
        raise ValueError(f"{what} must be a finite number, got {_short(value)}") from None
    if not math.isfinite(result):
        raise ValueError(f"{what} must be a finite number, got {_short(value)}")
    return result


def _positive_float(value, what: str) -> float:
    result = _finite_float(value, what)
    if result <= 0:
        raise ValueError(f"{what} must be positive, got {_short(value)}")
    return result

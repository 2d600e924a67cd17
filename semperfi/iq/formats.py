"""Sample formats of complex IQ files, named as GNSS-SDR's file source names them (`item_type`).

Every format stores one complex sample as I then Q, little-endian. Decoding gives complex64 with the raw integer
values (no normalisation, as GNSS-SDR does); encoding multiplies by a scale, rounds, clips and counts the clipping.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SampleFormat:
    """How one complex sample is laid out on disk."""
    name: str                 # GNSS-SDR item_type: 'ibyte', 'ishort', 'gr_complex'
    item_dtype: np.dtype      # numpy dtype of one stored item (an I or Q integer, or a whole complex64)
    bytes_per_sample: int     # bytes of one complex sample (I and Q together)
    sigmf_datatype: str       # SigMF core:datatype

    @property
    def items_per_sample(self) -> int:
        """2 for interleaved integers (I, Q), 1 for complex floats."""
        return self.bytes_per_sample // self.item_dtype.itemsize

    @property
    def is_integer(self) -> bool:
        return self.item_dtype.kind == "i"


IBYTE = SampleFormat("ibyte", np.dtype("<i1"), 2, "ci8")
ISHORT = SampleFormat("ishort", np.dtype("<i2"), 4, "ci16_le")
GR_COMPLEX = SampleFormat("gr_complex", np.dtype("<c8"), 8, "cf32_le")

FORMATS: tuple[SampleFormat, ...] = (IBYTE, ISHORT, GR_COMPLEX)
_ALIASES = {"cfloat": GR_COMPLEX}
_BY_NAME = {f.name: f for f in FORMATS} | _ALIASES
_BY_SIGMF = {f.sigmf_datatype: f for f in FORMATS}
FORMAT_NAMES: tuple[str, ...] = tuple(_BY_NAME)


def format_by_name(name: str) -> SampleFormat:
    """The format GNSS-SDR calls `name` ('ibyte', 'ishort', 'gr_complex' or its alias 'cfloat')."""
    key = name.strip().lower() if isinstance(name, str) else None
    if key not in _BY_NAME:
        raise ValueError(f"unknown sample format {_short(name)}; valid formats: {', '.join(FORMAT_NAMES)}")
    return _BY_NAME[key]


def format_by_sigmf_datatype(datatype: str) -> SampleFormat:
    """The format whose SigMF core:datatype is `datatype` ('ci8', 'ci16_le', 'cf32_le')."""
    if not isinstance(datatype, str) or datatype not in _BY_SIGMF:
        raise ValueError(f"unsupported SigMF datatype {_short(datatype)}; supported: {', '.join(_BY_SIGMF)}")
    return _BY_SIGMF[datatype]


def as_format(fmt: SampleFormat | str) -> SampleFormat:
    """Accept a SampleFormat or its name, so callers can pass a CLI string straight through."""
    if isinstance(fmt, SampleFormat):
        return fmt
    return format_by_name(fmt)


def decode_items(items: np.ndarray, fmt: SampleFormat) -> np.ndarray:
    """Stored items (whole samples) -> a new complex64 array of I + jQ, raw values, not normalised."""
    if fmt.is_integer:
        # Interleaved I,Q integers cast to float32 *are* a complex64 array in memory: one cast, no temporaries.
        return np.asarray(items).astype(np.float32).view(np.complex64)
    return np.array(items, dtype=np.complex64)   # a copy in native byte order, detached from any memmap


def encode_samples(samples: np.ndarray, fmt: SampleFormat, scale: float = 1.0) -> tuple[np.ndarray, int]:
    """Complex samples -> (items in `fmt` ready to write, number of complex samples clipped).

    Integers: I and Q are multiplied by `scale`, rounded to nearest and clipped to the integer range; a sample
    counts as clipped when I or Q had to be. Floats: multiplied by `scale`; overflow to inf counts as clipped.
    """
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
    with np.errstate(over="ignore", invalid="ignore"):
        scaled = iq * scale if scale != 1.0 else iq.copy()
        if not fmt.is_integer:
            out = scaled.astype("<f4").view(fmt.item_dtype)
            clipped = int((~np.isfinite(out)).sum())
            return out, clipped
        info = np.iinfo(fmt.item_dtype)
        np.rint(scaled, out=scaled)
        over = (scaled < info.min) | (scaled > info.max)
        clipped = int(over.reshape(-1, 2).any(axis=1).sum())
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

"""Samples from a pipe or standard input (`-` as FILE): read in whole samples, never seeking.

A pipe cannot be rewound or sized, so callers say how many samples they want; a stream that ends first is one
clear ValueError naming how much arrived (never a silently shorter, wrongly timed block).
"""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from .formats import SampleFormat, as_format, decode_items

MAX_READ_BYTES = 1 << 30   # one request never asks for more than this (a hostile --fs cannot exhaust memory)


def read_stream(stream: BinaryIO, fmt: SampleFormat | str, n_samples: int, skip_samples: int = 0) -> np.ndarray:
    """Skip `skip_samples`, then return exactly `n_samples` decoded samples (complex64) from `stream`."""
    fmt = as_format(fmt)
    per, size = fmt.samples_per_block, fmt.block_bytes
    for what, count in (("samples to skip", skip_samples), ("samples to read", n_samples)):
        if int(count) != count or count < 0 or count * size / per > MAX_READ_BYTES:
            raise ValueError(f"{what} must be a whole number below {MAX_READ_BYTES * per // size}, got {count!r}")
    skip, n = int(skip_samples), int(n_samples)
    first, last = skip // per, -(-(skip + n) // per)     # whole blocks (bytes, when packed)
    _read_exactly(stream, first * size, "skipping", fmt)
    raw = _read_exactly(stream, (last - first) * size, "reading", fmt)
    samples = decode_items(np.frombuffer(raw, dtype=fmt.item_dtype), fmt)
    return samples[skip - first * per:skip - first * per + n]


def _read_exactly(stream: BinaryIO, n_bytes: int, doing: str, fmt: SampleFormat) -> bytes:
    parts, got = [], 0
    while got < n_bytes:
        block = stream.read(min(n_bytes - got, 1 << 22))
        if not block:
            per = fmt.samples_per_block / fmt.block_bytes
            raise ValueError(f"input stream ended while {doing}: {int(got * per)} of {int(n_bytes * per)} "
                             f"{fmt.name} samples arrived")
        parts.append(block)
        got += len(block)
    return b"".join(parts)

"""Chunked, memory-mapped reading of IQ files: a 48 GB recording costs only the chunk in hand."""

from __future__ import annotations

import math
import operator
import os
from pathlib import Path
from typing import Iterator

import mmap

import numpy as np

from .formats import (SampleFormat, _finite_float, _positive_float, _short, as_format, decode_items,
                      format_by_sigmf_datatype)
from .sigmf import META_SUFFIX, SigmfMeta, find_sidecar, read_sigmf_meta

DEFAULT_CHUNK_SAMPLES = 1 << 20   # 8 MiB of complex64; receivers usually ask for whole milliseconds instead


def _count(value, what: str) -> int:
    """A sample index or count from the caller as int, or one ValueError line (floats are refused, not rounded)."""
    try:
        result = operator.index(value)
    except TypeError:
        raise ValueError(f"{what} must be an integer, got {_short(value)}") from None
    if result < 0:
        raise ValueError(f"{what} must not be negative, got {result}")
    return result


class IqReader:
    """A read-only view of an IQ file as complex64 samples (I + jQ, raw values as stored, not normalised).

    Iterating yields chunks of `chunk_samples` samples (the last may be shorter); `read` gives random access.
    A file ending in a partial sample (an interrupted recording) is read up to its last whole sample and the
    leftover byte count is kept in `truncated_bytes`.
    """

    def __init__(self, path: str | os.PathLike, fmt: SampleFormat | str, fs_hz: float | None = None,
                 chunk_samples: int = DEFAULT_CHUNK_SAMPLES, *, if_hz: float = 0.0,
                 sidecar: SigmfMeta | None = None):
        self.path = Path(path)
        self.fmt = as_format(fmt)
        self.fs_hz = None if fs_hz is None else _positive_float(fs_hz, "sample rate (fs_hz)")
        self.if_hz = _finite_float(if_hz, "intermediate frequency (if_hz)")
        if not self.fmt.is_complex and self.fs_hz is not None and not 0 < abs(self.if_hz) < self.fs_hz / 2:
            # A real signal's spectrum is symmetric: L1 must sit at an IF strictly inside (0, fs/2) to be seen.
            raise ValueError(f"real-valued samples ({self.fmt.name}) need the IF of L1 between 0 and fs/2 "
                             f"({self.fs_hz / 2:g} Hz): pass --if <Hz>, got {self.if_hz:g} Hz")
        self.chunk_samples = _count(chunk_samples, "chunk_samples")
        if self.chunk_samples == 0:
            raise ValueError("chunk_samples must be at least 1")
        self.sidecar = sidecar

        if self.path.suffix == META_SUFFIX:
            raise ValueError(f"{self.path} is a SigMF metadata file; pass the data file it describes")
        try:
            size_bytes = self.path.stat().st_size
        except FileNotFoundError:
            raise ValueError(f"IQ file not found: {self.path}") from None
        except OSError as exc:
            raise ValueError(f"cannot read IQ file {self.path}: {exc.strerror or exc}") from None
        if not self.path.is_file():
            raise ValueError(f"IQ file {self.path} is not a regular file")
        if size_bytes == 0:
            raise ValueError(f"IQ file {self.path} is empty")
        n_blocks, self.truncated_bytes = divmod(size_bytes, self.fmt.block_bytes)
        self.n_samples = n_blocks * self.fmt.samples_per_block
        if self.n_samples == 0:
            raise ValueError(f"IQ file {self.path} holds {size_bytes} bytes, less than one {self.fmt.name} sample "
                             f"({self.fmt.block_bytes} bytes)")
        try:
            # Map only the whole samples, so a trailing partial sample can never leak into the data.
            self._items = np.memmap(self.path, dtype=self.fmt.item_dtype, mode="r",
                                    shape=(n_blocks * self.fmt.items_per_block,))
        except (OSError, ValueError) as exc:
            raise ValueError(f"cannot map IQ file {self.path}: {exc}") from None

    @property
    def duration_s(self) -> float:
        """Length of the recording in seconds (needs the sample rate)."""
        if self.fs_hz is None:
            raise ValueError(f"sample rate of {self.path} unknown: pass fs_hz (--fs)")
        return self.n_samples / self.fs_hz

    def __len__(self) -> int:
        return self.n_samples

    def read(self, start_sample: int, n_samples: int) -> np.ndarray:
        """Samples [start_sample, start_sample + n_samples) as a new complex64 array; shorter (possibly empty)
        where the file ends first, so callers check len() near the end of a recording."""
        start = _count(start_sample, "start_sample")
        count = _count(n_samples, "n_samples")
        if self._items is None:
            raise ValueError(f"IQ file {self.path} is closed")
        stop = min(start + count, self.n_samples)
        start = min(start, stop)
        k, per = self.fmt.items_per_block, self.fmt.samples_per_block
        first, last = start // per, -(-stop // per)   # the whole blocks (bytes, when packed) holding the samples
        # The slice is a view of the mapping; decode copies it, so no caller ever holds the mapping open.
        samples = decode_items(self._items[first * k:last * k], self.fmt)
        return samples if per == 1 else samples[start - first * per:stop - first * per]

    def chunks(self, start_sample: int = 0, stop_sample: int | None = None) -> Iterator[np.ndarray]:
        """Consecutive chunks of `chunk_samples` from start_sample to stop_sample (default: end of file)."""
        start = _count(start_sample, "start_sample")
        stop = self.n_samples if stop_sample is None else min(_count(stop_sample, "stop_sample"), self.n_samples)
        for first in range(start, stop, self.chunk_samples):
            n = min(self.chunk_samples, stop - first)
            chunk = self.read(first, n)
            self.release(first, n)
            yield chunk

    def release(self, start_sample: int, n_samples: int) -> None:
        """Tell the kernel a streamed chunk's pages are done with: a sequential pass then keeps a bounded resident
        set however long the recording (file pages would otherwise stay mapped, and counted, to the end)."""
        mm = getattr(self._items, "_mmap", None)
        if mm is None or not hasattr(mmap, "MADV_DONTNEED"):
            return
        page = mmap.PAGESIZE
        per, size = self.fmt.samples_per_block, self.fmt.block_bytes
        lo = (start_sample // per * size) // page * page
        hi = ((start_sample + n_samples) // per * size) // page * page
        if hi > lo:
            try:
                mm.madvise(mmap.MADV_DONTNEED, lo, hi - lo)
            except (OSError, ValueError):
                pass   # advice only

    def __iter__(self) -> Iterator[np.ndarray]:
        return self.chunks()

    def close(self) -> None:
        """Drop the mapping (numpy unmaps when the last reference goes; chunks handed out are copies)."""
        self._items = None

    def __enter__(self) -> IqReader:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def __repr__(self) -> str:
        rate = "unknown" if self.fs_hz is None else f"{self.fs_hz:g} Hz"
        swapped = " (I/Q swapped)" if self.fmt.iq_swapped else ""
        return (f"IqReader({str(self.path)!r}, {self.fmt.name}{swapped}, fs={rate}, if={self.if_hz:g} Hz, "
                f"{self.n_samples} samples, truncated_bytes={self.truncated_bytes})")


def _agree(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-6)


def open_iq(path: str | os.PathLike, fmt: SampleFormat | str | None = None, fs_hz: float | None = None,
            if_hz: float | None = None, chunk_samples: int = DEFAULT_CHUNK_SAMPLES) -> IqReader:
    """Open an IQ file, taking format, sample rate and IF from its SigMF sidecar where the caller gives none.

    Values given by both must agree (a wrong --fs silently breaks acquisition, so it is an error, not an
    override). Without a sidecar the caller must give the format and the rate; IF defaults to 0 (baseband).
    """
    path = Path(path)
    if not path.exists():   # say so before complaining about a missing format or rate
        raise ValueError(f"IQ file not found: {path}")
    user_fmt = None if fmt is None else as_format(fmt)
    user_fs = None if fs_hz is None else _positive_float(fs_hz, "sample rate (fs_hz)")
    user_if = None if if_hz is None else _finite_float(if_hz, "intermediate frequency (if_hz)")

    meta_path = find_sidecar(path)
    meta = read_sigmf_meta(meta_path) if meta_path is not None else None
    side_fmt = side_fs = side_if = None
    if meta is not None:
        try:
            side_fmt = format_by_sigmf_datatype(meta.datatype)
        except ValueError as exc:
            raise ValueError(f"SigMF sidecar {meta_path}: {exc}") from None
        side_fs = meta.sample_rate_hz
        side_if = meta.implied_if_hz()

    if user_fmt is not None and side_fmt is not None and user_fmt.unswapped != side_fmt:
        raise ValueError(f"format {user_fmt.name!r} disagrees with SigMF sidecar {meta_path} "
                         f"(core:datatype {side_fmt.sigmf_datatype!r} = {side_fmt.name!r})")
    if user_fs is not None and side_fs is not None and not _agree(user_fs, side_fs):
        raise ValueError(f"sample rate {user_fs:g} Hz disagrees with SigMF sidecar {meta_path} "
                         f"(core:sample_rate {side_fs:g} Hz)")
    if user_if is not None and side_if is not None and not _agree(user_if, side_if):
        raise ValueError(f"IF {user_if:g} Hz disagrees with SigMF sidecar {meta_path} ({side_if:g} Hz)")

    final_fmt = user_fmt or side_fmt   # the user's, as it may say the front end swapped I and Q
    final_fs = user_fs if user_fs is not None else side_fs
    final_if = user_if if user_if is not None else (side_if if side_if is not None else 0.0)
    why = f"no SigMF sidecar {path.with_suffix(META_SUFFIX).name}" if meta is None else \
        f"SigMF sidecar {meta_path} does not say"
    if final_fmt is None:
        raise ValueError(f"sample format of {path} unknown ({why}): "
                         "pass --format ibyte|ishort|gr_complex|byte|short|<SigMF datatype>")
    if final_fs is None:
        raise ValueError(f"sample rate of {path} unknown ({why}): pass --fs <Hz>")
    return IqReader(path, final_fmt, final_fs, chunk_samples, if_hz=final_if, sidecar=meta)

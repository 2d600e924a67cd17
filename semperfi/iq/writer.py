"""Writing IQ files in a GNSS-SDR format, with a SigMF sidecar so the file describes itself."""

from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path

import numpy as np

from .formats import SampleFormat, _positive_float, as_format, encode_samples
from .sigmf import META_SUFFIX, NAMESPACE, build_sigmf_meta, sidecar_path, write_sigmf_meta


class IqWriter:
    """Append complex chunks to an IQ file; a context manager that leaves `<stem>.sigmf-meta` beside the file.

    `write` multiplies by `scale`, rounds to nearest and clips to the integer range (counted in
    `clipped_samples`, so callers can report saturation). Every write is flushed and the sidecar is written when
    the file is opened, so a run that dies half-way still leaves a readable, described partial recording.
    """

    def __init__(self, path: str | os.PathLike, fmt: SampleFormat | str, fs_hz: float, if_hz: float = 0.0,
                 scale: float = 1.0, metadata: dict | None = None, *, description: str = "",
                 datetime_utc: _dt.datetime | str | None = None, center_frequency_hz: float | None = None):
        self.path = Path(path)
        self.fmt = as_format(fmt)
        self.scale = _positive_float(scale, "scale")
        if self.path.suffix == META_SUFFIX:
            raise ValueError(f"{self.path} would be the data file's own sidecar; name the data file .bin or .dat")
        self.meta_path = sidecar_path(self.path)
        extra = dict(metadata or {})
        if "scale" in extra or f"{NAMESPACE}:scale" in extra:
            raise ValueError("metadata key 'scale' is reserved; pass scale instead")
        extra = {"scale": self.scale, **extra}
        # Built (and so validated) before the data file is touched: a bad rate must not truncate a file.
        self._meta = build_sigmf_meta(datatype=self.fmt.sigmf_datatype, sample_rate_hz=fs_hz,
                                      dataset=self.path.name, if_hz=if_hz, center_frequency_hz=center_frequency_hz,
                                      description=description, datetime_utc=datetime_utc, extra=extra)
        self.fs_hz = self._meta["global"]["core:sample_rate"]
        self.if_hz = self._meta["global"][f"{NAMESPACE}:if_hz"]
        self.samples_written = 0
        self.clipped_samples = 0
        try:
            self._file = open(self.path, "wb")
        except OSError as exc:
            raise ValueError(f"cannot create IQ file {self.path}: {exc.strerror or exc}") from None
        try:
            write_sigmf_meta(self.meta_path, self._meta)
        except ValueError:
            self._file.close()
            raise

    @property
    def clipped_fraction(self) -> float:
        """Share of written samples whose I or Q was clipped (0 when nothing written yet)."""
        return self.clipped_samples / self.samples_written if self.samples_written else 0.0

    def write(self, samples: np.ndarray) -> int:
        """Convert and append a 1-D complex chunk; returns how many of its samples were clipped."""
        if self._file is None:
            raise ValueError(f"IQ file {self.path} is already closed")
        items, clipped = encode_samples(samples, self.fmt, self.scale)
        self._file.write(items)
        self._file.flush()   # to the OS: survives a crash of this process (not a power cut; fsync is too slow)
        self.samples_written += len(items) // self.fmt.items_per_block
        self.clipped_samples += clipped
        return clipped

    def annotate(self, key: str, value) -> None:
        """A fact about the samples learnt while writing them (JSON-able), in the sidecar's semperfi namespace."""
        self._meta["global"][f"{NAMESPACE}:{key}"] = value

    def close(self) -> None:
        """Close the data file and (re)write the sidecar; calling it twice is harmless."""
        if self._file is None:
            return
        self._file.close()
        self._file = None
        write_sigmf_meta(self.meta_path, self._meta)

    def __enter__(self) -> IqWriter:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()   # also on an exception: what was written stays, described

    def __repr__(self) -> str:
        return (f"IqWriter({str(self.path)!r}, {self.fmt.name}, fs={self.fs_hz:g} Hz, "
                f"{self.samples_written} samples, {self.clipped_samples} clipped)")

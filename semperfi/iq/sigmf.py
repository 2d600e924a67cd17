"""SigMF metadata sidecars (https://sigmf.org), built, validated and read through the SigMF reference library.

GNSS-SDR users name their data files `.bin`/`.dat`, not `.sigmf-data`, so the sidecar sits next to the data file
with the same stem (`out.bin` -> `out.sigmf-meta`) and `core:dataset` records the data file's name. Our own
values live in the declared `semperfi:` namespace: `semperfi:if_hz` and whatever the caller adds.

A sidecar read from disk is input from outside: its size is bounded and it must be UTF-8 JSON holding a 'global'
object before the library sees it, and the library's schema then checks it whole; anything wrong ends in one
BadInput line naming the file, not a traceback.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from jsonschema import ValidationError   # what the library's validator raises
from sigmf import SigMFFile
from sigmf.keys import (DATASET_KEY, DATATYPE_KEY, DATETIME_KEY, DESCRIPTION_KEY, EXTENSIONS_KEY, FREQUENCY_KEY,
                        RECORDER_KEY, SAMPLE_RATE_KEY, SAMPLE_START_KEY)

from ..errors import BadInput
from ..gps import L1_HZ
from .formats import _finite_float, _positive_float

META_SUFFIX = ".sigmf-meta"
MAX_META_BYTES = 1 << 20   # real sidecars are a few kB; anything bigger is not one we wrote or can trust
MAX_SEGMENTS = 10_000      # captures + annotations: the schema takes ~25 us on each, and 1 MB holds 300 000
NAMESPACE = "semperfi"
_IF_KEY = f"{NAMESPACE}:if_hz"


@dataclass(frozen=True)
class SigmfMeta:
    """The fields of a sidecar the IQ reader cares about; None where the sidecar is silent."""
    path: Path | None
    datatype: str                         # core:datatype, e.g. 'ci16_le' (SigMF requires it)
    sample_rate_hz: float | None          # core:sample_rate
    if_hz: float | None                   # semperfi:if_hz
    center_frequency_hz: float | None     # core:frequency of the first capture (RF centre)
    dataset: str | None                   # core:dataset (the data file's name)
    description: str | None
    datetime_utc: str | None              # core:datetime of the first capture, ISO 8601 as written
    extra: dict = field(default_factory=dict, hash=False)   # the other semperfi:* keys, prefix stripped

    def implied_if_hz(self) -> float | None:
        """Where L1 sits in the recorded band: semperfi:if_hz, else L1 minus the RF centre frequency when that puts
        L1 inside the complex band (|IF| <= fs/2); None when the sidecar does not say."""
        if self.if_hz is not None:
            return self.if_hz
        if self.center_frequency_hz is None or self.sample_rate_hz is None:
            return None
        if_hz = L1_HZ - self.center_frequency_hz
        return if_hz if abs(if_hz) <= self.sample_rate_hz / 2 else None


def sidecar_path(data_path: str | os.PathLike) -> Path:
    """Where the sidecar of `data_path` is written: same folder and stem, suffix `.sigmf-meta`."""
    return Path(data_path).with_suffix(META_SUFFIX)


def find_sidecar(data_path: str | os.PathLike) -> Path | None:
    """The existing sidecar of `data_path`: `<stem>.sigmf-meta`, else `<data file name>.sigmf-meta`, else None."""
    p = Path(data_path)
    for candidate in (p.with_suffix(META_SUFFIX), Path(str(p) + META_SUFFIX)):
        if candidate.is_file():
            return candidate
    return None


def _iso_utc(when: _dt.datetime | str) -> str:
    if isinstance(when, str):
        return when
    if not isinstance(when, _dt.datetime):
        raise ValueError(f"capture datetime must be a datetime or an ISO 8601 string, got {when!r}")
    if when.tzinfo is None:   # a naive time is taken as UTC, which is what SigMF wants anyway
        when = when.replace(tzinfo=_dt.timezone.utc)
    return when.astimezone(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _validated(record: SigMFFile, where: str) -> SigMFFile:
    """`record` once the library's validator passes it (schema, declared namespaces, capture order); else one
    BadInput line. The schema's message quotes the bad value, which a hostile file makes huge: it is cut short."""
    try:
        with warnings.catch_warnings():   # an undeclared namespace in someone else's file is theirs to fix
            warnings.simplefilter("ignore", DeprecationWarning)
            record.validate()
    except ValidationError as exc:
        why = exc.message.splitlines()[0] if exc.message else "invalid"
        why = why if len(why) <= 100 else why[:97] + "..."
        raise BadInput(f"{where}: not valid SigMF ({exc.json_path}: {why})") from None
    return record


def build_sigmf_meta(*, datatype: str, sample_rate_hz: float, dataset: str, if_hz: float = 0.0,
                     center_frequency_hz: float | None = None, description: str = "",
                     datetime_utc: _dt.datetime | str | None = None, extra: dict | None = None) -> dict:
    """The sidecar as a JSON-ready dict, validated by the SigMF library (which also sets core:version to the
    specification it implements). `center_frequency_hz` defaults to L1 - if_hz; `extra` keys go under
    `semperfi:` (a key already carrying the prefix keeps it)."""
    sample_rate_hz = _positive_float(sample_rate_hz, "sample rate (fs_hz)")
    if_hz = _finite_float(if_hz, "intermediate frequency (if_hz)")
    if center_frequency_hz is None:
        center_frequency_hz = L1_HZ - if_hz
    center_frequency_hz = _finite_float(center_frequency_hz, "centre frequency")
    glob = {
        DATATYPE_KEY: datatype,
        SAMPLE_RATE_KEY: sample_rate_hz,
        DESCRIPTION_KEY: str(description),
        RECORDER_KEY: NAMESPACE,
        DATASET_KEY: str(dataset),
        # SigMF asks every namespace but core to be declared; optional, so other readers may ignore it.
        EXTENSIONS_KEY: [{"name": NAMESPACE, "version": "0.1.0", "optional": True}],
        _IF_KEY: if_hz,
    }
    for key, value in (extra or {}).items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"metadata keys must be non-empty strings, got {key!r}")
        full = key if key.startswith(NAMESPACE + ":") else f"{NAMESPACE}:{key}"
        if full == _IF_KEY:
            raise ValueError("metadata key 'if_hz' is reserved; pass if_hz instead")
        glob[full] = value
    capture = {FREQUENCY_KEY: center_frequency_hz}
    if datetime_utc is not None:
        capture[DATETIME_KEY] = _iso_utc(datetime_utc)
    record = SigMFFile(global_info=glob)
    record.add_capture(0, capture)
    _validated(record, "metadata to write")
    return {"global": record.get_global_info(), "captures": record.get_captures(),
            "annotations": record.get_annotations()}


def write_sigmf_meta(meta_path: str | os.PathLike, meta: dict) -> Path:
    """Write `meta` (from build_sigmf_meta) atomically: a reader never sees a half-written sidecar."""
    meta_path = Path(meta_path)
    try:
        text = json.dumps(meta, indent=2, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"metadata is not JSON-serialisable: {exc}") from None
    tmp = meta_path.with_name(meta_path.name + ".tmp")
    try:
        tmp.write_text(text + "\n", encoding="utf-8")
        os.replace(tmp, meta_path)
    except OSError as exc:
        raise ValueError(f"cannot write SigMF sidecar {meta_path}: {exc.strerror or exc}") from None
    return meta_path


def _reject_constant(name: str):
    raise ValueError(f"{name} is not valid JSON")


def read_sigmf_meta(meta_path: str | os.PathLike) -> SigmfMeta:
    """Parse a sidecar and have the SigMF library validate it; any problem is one BadInput line naming the file."""
    meta_path = Path(meta_path)
    where = f"SigMF sidecar {meta_path}"
    if not meta_path.is_file():
        raise BadInput(f"{where}: not a regular file")
    try:
        with open(meta_path, "rb") as f:
            raw = f.read(MAX_META_BYTES + 1)   # bounded even if the file grows or lies about its size
    except OSError as exc:
        raise BadInput(f"{where}: cannot read: {exc.strerror or exc}") from None
    if len(raw) > MAX_META_BYTES:
        raise BadInput(f"{where}: larger than {MAX_META_BYTES} bytes, refusing to parse it")
    try:
        doc = json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)
    except UnicodeDecodeError:
        raise BadInput(f"{where}: not UTF-8 text") from None
    except (ValueError, RecursionError) as exc:   # JSONDecodeError is a ValueError; deep nesting recurses
        first_line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise BadInput(f"{where}: malformed JSON ({first_line})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("global"), dict):
        raise BadInput(f"{where}: expected a JSON object with a 'global' object")

    # What other writers leave out and the schema defaults: empty captures and annotations, a capture at sample 0.
    segments = doc.setdefault("captures", []), doc.setdefault("annotations", [])
    if sum(len(s) for s in segments if isinstance(s, list)) > MAX_SEGMENTS:
        raise BadInput(f"{where}: more than {MAX_SEGMENTS} captures and annotations, refusing to check them")
    for capture in segments[0] if isinstance(segments[0], list) else ():   # not a list: the schema says so below
        if isinstance(capture, dict):
            capture.setdefault(SAMPLE_START_KEY, 0)
    try:   # the library sets core:version to the specification it checks against
        record = _validated(SigMFFile(metadata=doc), where)
    except RecursionError:   # nested shallowly enough for the JSON parser, too deep for the library's copy
        raise BadInput(f"{where}: not valid SigMF (nested too deep)") from None
    glob, first = record.get_global_info(), (record.get_captures() or [{}])[0]
    try:
        if_hz = _finite_float(glob[_IF_KEY], _IF_KEY) if _IF_KEY in glob else None   # ours: the schema knows not
    except ValueError as exc:
        raise BadInput(f"{where}: {exc}") from None

    def number(obj: dict, key: str) -> float | None:   # the schema checked type and range
        return float(obj[key]) if key in obj else None

    return SigmfMeta(
        path=meta_path,
        datatype=glob[DATATYPE_KEY],
        sample_rate_hz=number(glob, SAMPLE_RATE_KEY),
        if_hz=if_hz,
        center_frequency_hz=number(first, FREQUENCY_KEY),
        dataset=glob.get(DATASET_KEY),
        description=glob.get(DESCRIPTION_KEY),
        datetime_utc=first.get(DATETIME_KEY),
        extra={k[len(NAMESPACE) + 1:]: v for k, v in glob.items() if k.startswith(NAMESPACE + ":") and k != _IF_KEY},
    )

"""IQ sample streams: GNSS-SDR file formats, chunked memory-mapped reading, writing, SigMF sidecars."""

from .formats import (BYTE, FORMAT_NAMES, FORMATS, GR_COMPLEX, IBYTE, ISHORT, SHORT, SIGMF_DATATYPES, SampleFormat,
                      as_format, decode_items, with_iq_swap,
                      encode_samples, format_by_name, format_by_sigmf_datatype)
from .reader import DEFAULT_CHUNK_SAMPLES, IqReader, open_iq
from .sigmf import (MAX_META_BYTES, SigmfMeta, build_sigmf_meta, find_sidecar, read_sigmf_meta, sidecar_path,
                    write_sigmf_meta)
from .writer import IqWriter

__all__ = [
    "BYTE", "FORMAT_NAMES", "FORMATS", "GR_COMPLEX", "IBYTE", "ISHORT", "SHORT", "SIGMF_DATATYPES", "SampleFormat",
    "as_format", "decode_items", "encode_samples", "format_by_name", "format_by_sigmf_datatype", "with_iq_swap",
    "DEFAULT_CHUNK_SAMPLES", "IqReader", "open_iq",
    "MAX_META_BYTES", "SigmfMeta", "build_sigmf_meta", "find_sidecar", "read_sigmf_meta", "sidecar_path",
    "write_sigmf_meta",
    "IqWriter",
]

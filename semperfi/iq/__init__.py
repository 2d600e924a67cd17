"""IQ sample streams: GNSS-SDR file formats, chunked memory-mapped reading, writing, SigMF sidecars."""

from ..face import lazy_face

# the names other rooms use, by the module that gives them (loaded when first used)
__all__, __getattr__, __dir__ = lazy_face(__name__, {
    "formats": ("GR_COMPLEX", "IBYTE", "ISHORT", "as_format", "encode_samples", "format_by_name",
                "format_by_sigmf_datatype", "with_iq_swap"),
    "reader": ("open_iq",),
    "rinex": ("read_rinex_nav",),
    "sigmf": ("build_sigmf_meta", "find_sidecar", "read_sigmf_meta", "sidecar_path", "write_sigmf_meta"),
    "source": ("SampleSource", "SourceError", "chunk_seconds", "open_source"),
    "writer": ("IqWriter",),
})

"""Claims about IQ files: formats as GNSS-SDR lays them out, chunked reading, writing, SigMF sidecars."""

import datetime
import json
import struct
import tracemalloc
import warnings

import numpy as np
import pytest
import sigmf

from semperfi.errors import BadInput
from semperfi.gps.constants import L1_HZ
from semperfi.iq import GR_COMPLEX, IBYTE, ISHORT, IqWriter, format_by_name, open_iq, read_sigmf_meta
from semperfi.iq.formats import FORMAT_NAMES
from semperfi.iq.reader import IqReader
from semperfi.iq.sigmf import MAX_META_BYTES

FS_HZ = 4.092e6
FORMATS = ["ibyte", "ishort", "gr_complex"]


def _noise(n, amplitude, seed=1):
    rng = np.random.default_rng(seed)
    return (amplitude * (rng.standard_normal(n) + 1j * rng.standard_normal(n))).astype(np.complex64)


def _one_line_value_error(excinfo):
    message = str(excinfo.value)
    assert message and "\n" not in message, f"error should be one line, got {message!r}"
    return message


# --- formats -----------------------------------------------------------------------------------------------------

def test_formats_describe_gnss_sdr_item_types_and_sigmf_datatypes():
    assert (IBYTE.bytes_per_sample, IBYTE.sigmf_datatype, IBYTE.item_dtype) == (2, "ci8", np.dtype("i1"))
    assert (ISHORT.bytes_per_sample, ISHORT.sigmf_datatype, ISHORT.item_dtype) == (4, "ci16_le", np.dtype("<i2"))
    assert (GR_COMPLEX.bytes_per_sample, GR_COMPLEX.sigmf_datatype) == (8, "cf32_le")
    assert format_by_name("cfloat") is GR_COMPLEX
    assert format_by_name("ishort") is ISHORT


def test_unknown_format_name_lists_the_valid_ones():
    with pytest.raises(ValueError) as excinfo:
        format_by_name("fc32")
    message = _one_line_value_error(excinfo)
    for name in ("ibyte", "ishort", "gr_complex", "cfloat"):
        assert name in message, f"{name!r} missing from {message!r}"
    assert set(FORMAT_NAMES) == {"ibyte", "ishort", "gr_complex", "cfloat", "byte", "short", "float",
                                 "real2", "iq2", "real2sm", "iq2sm", "real4", "iq4"}


# --- writing and the byte layout ---------------------------------------------------------------------------------

@pytest.mark.parametrize("fmt, amplitude, scale", [("ibyte", 1.0, 30.0), ("ishort", 1.0, 3000.0),
                                                   ("gr_complex", 1.0, 1.0)])
def test_round_trip_within_quantization(tmp_path, fmt, amplitude, scale):
    x = _noise(10_000, amplitude)
    path = tmp_path / "rt.bin"
    with IqWriter(path, fmt, FS_HZ, scale=scale) as w:
        w.write(x[:3000])
        w.write(x[3000:])
    assert w.clipped_samples == 0 and w.samples_written == len(x)
    y = IqReader(path, fmt, FS_HZ).read(0, len(x))
    assert y.dtype == np.complex64 and len(y) == len(x)
    if fmt == "gr_complex":
        assert np.array_equal(y, x), "gr_complex must round-trip bit-exactly"
    else:
        err = max(np.abs(y.real - x.real * scale).max(), np.abs(y.imag - x.imag * scale).max())
        assert err <= 0.5 + 1e-3, f"{fmt}: worst error {err:.4f} LSB exceeds half a quantization step"


@pytest.mark.parametrize("fmt, packed", [
    ("ibyte", struct.pack("<6b", 1, 2, -3, -4, 127, -128)),
    ("ishort", struct.pack("<6h", 1, 2, -3, -4, 32767, -32768)),
    ("gr_complex", struct.pack("<6f", 1, 2, -3, -4, 0.5, -0.25)),
], ids=FORMATS)
def test_interleaving_is_i_then_q_little_endian(tmp_path, fmt, packed):
    if fmt == "ibyte":
        samples = np.array([1 + 2j, -3 - 4j, 127 - 128j], np.complex64)
    elif fmt == "ishort":
        samples = np.array([1 + 2j, -3 - 4j, 32767 - 32768j], np.complex64)
    else:
        samples = np.array([1 + 2j, -3 - 4j, 0.5 - 0.25j], np.complex64)
    written = tmp_path / "w.bin"
    with IqWriter(written, fmt, FS_HZ) as w:
        w.write(samples)
    assert written.read_bytes() == packed, "written bytes must be I0 Q0 I1 Q1 ... little-endian"

    hand = tmp_path / "hand.bin"
    hand.write_bytes(packed)
    got = IqReader(hand, fmt, FS_HZ).read(0, 3)
    assert np.array_equal(got, samples), f"hand-packed I,Q read back as {got}, expected {samples}"


def test_rounding_to_nearest_and_clipping_counted(tmp_path):
    x = np.array([0.4 + 0.6j, -0.6 - 0.4j, 126.6 + 0j,    # rounding, no clipping
                  127.6 + 0j, 0 - 128.6j, 1000 + 1000j, -1e30 + 0j], np.complex64)   # 4 samples clip
    path = tmp_path / "clip.bin"
    with IqWriter(path, "ibyte", FS_HZ) as w:
        assert w.write(x) == 4
    assert w.clipped_samples == 4 and w.samples_written == 7
    assert w.clipped_fraction == pytest.approx(4 / 7)
    assert list(struct.unpack("<14b", path.read_bytes())) == [0, 1, -1, 0, 127, 0,
                                                              127, 0, 0, -128, 127, 127, -128, 0]


def test_ishort_clipping_counts_a_sample_once_even_if_i_and_q_both_clip(tmp_path):
    with IqWriter(tmp_path / "s.bin", "ishort", FS_HZ, scale=1e5) as w:
        clipped = w.write(np.array([1 + 1j, 0.1 + 0.1j, -1 + 0j], np.complex64))
    assert clipped == 2
    assert np.array_equal(IqReader(tmp_path / "s.bin", "ishort", FS_HZ).read(0, 3),
                          np.array([32767 + 32767j, 10000 + 10000j, -32768 + 0j], np.complex64))


@pytest.mark.parametrize("bad", [np.array([np.nan + 0j]), np.ones(4, np.float32), np.ones((2, 2), np.complex64)])
def test_writer_refuses_bad_chunks_with_one_line(tmp_path, bad):
    with IqWriter(tmp_path / "b.bin", "ishort", FS_HZ) as w:
        with pytest.raises(ValueError) as excinfo:
            w.write(bad)
        _one_line_value_error(excinfo)
    assert (tmp_path / "b.bin").stat().st_size == 0, "a refused chunk must not be half-written"


def test_every_write_is_flushed_and_described_before_close(tmp_path):
    path = tmp_path / "partial.bin"
    w = IqWriter(path, "ibyte", FS_HZ)
    w.write(np.ones(1000, np.complex64))
    # Another process (or this one after a crash) sees the data and the sidecar already.
    assert path.stat().st_size == 2000
    assert open_iq(path).n_samples == 1000
    w.close()
    w.close()


def test_writer_bad_arguments_are_one_line(tmp_path):
    for kwargs in ({"fs_hz": -1.0}, {"fs_hz": float("nan")}, {"fs_hz": "4e6"}, {"fs_hz": FS_HZ, "scale": 0.0},
                   {"fs_hz": FS_HZ, "metadata": {"obj": object()}}, {"fs_hz": FS_HZ, "metadata": {"if_hz": 1}}):
        with pytest.raises(ValueError) as excinfo:
            IqWriter(tmp_path / "x.bin", "ibyte", **kwargs)
        _one_line_value_error(excinfo)
    with pytest.raises(ValueError):
        IqWriter(tmp_path / "x.sigmf-meta", "ibyte", FS_HZ)


# --- reading -----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("chunk_samples", [1, 100, 333, 1000, 1001, 5000])
@pytest.mark.parametrize("fmt", FORMATS)
def test_chunks_reassemble_the_whole_file(tmp_path, fmt, chunk_samples):
    n = 1000
    x = _noise(n, 20.0)
    path = tmp_path / "c.bin"
    with IqWriter(path, fmt, FS_HZ) as w:
        w.write(x)
    whole = IqReader(path, fmt, FS_HZ).read(0, n)
    reader = IqReader(path, fmt, FS_HZ, chunk_samples=chunk_samples)
    chunks = list(reader)
    lengths = [len(c) for c in chunks]
    assert all(k == chunk_samples for k in lengths[:-1]) and 0 < lengths[-1] <= chunk_samples, lengths[-3:]
    assert np.array_equal(np.concatenate(chunks), whole), f"chunks of {chunk_samples} do not reassemble the file"
    assert reader.n_samples == n and len(reader) == n
    assert reader.duration_s == pytest.approx(n / FS_HZ)


def test_random_access_and_the_end_of_file(tmp_path):
    x = _noise(500, 50.0)
    path = tmp_path / "r.bin"
    with IqWriter(path, "ishort", FS_HZ) as w:
        w.write(x)
    r = IqReader(path, "ishort", FS_HZ)
    full = r.read(0, 500)
    assert np.array_equal(r.read(123, 77), full[123:200])
    assert np.array_equal(r.read(np.int64(450), 100), full[450:]), "a read past the end is shortened"
    assert len(r.read(500, 10)) == 0 and len(r.read(10_000, 10)) == 0
    assert np.array_equal(np.concatenate(list(r.chunks(100, 260))), full[100:260])
    for args in ((-1, 5), (0, -5), (1.5, 5), (0, "10")):
        with pytest.raises(ValueError) as excinfo:
            r.read(*args)
        _one_line_value_error(excinfo)


@pytest.mark.parametrize("fmt, extra_bytes", [("ishort", 3), ("ishort", 1), ("ibyte", 1), ("gr_complex", 7)])
def test_truncated_recording_is_read_to_its_last_whole_sample(tmp_path, fmt, extra_bytes):
    n = 257
    x = _noise(n, 10.0)
    path = tmp_path / "t.bin"
    with IqWriter(path, fmt, FS_HZ) as w:
        w.write(x)
    with open(path, "ab") as f:
        f.write(b"\x7f" * extra_bytes)   # a recorder killed mid-sample
    r = IqReader(path, fmt, FS_HZ, chunk_samples=100)
    assert (r.n_samples, r.truncated_bytes) == (n, extra_bytes)
    got = np.concatenate(list(r))
    assert len(got) == n
    assert np.array_equal(got, IqReader(path, fmt, FS_HZ).read(0, n + 10))


def test_empty_and_tiny_and_missing_files_are_one_line_errors(tmp_path):
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    tiny = tmp_path / "tiny.bin"
    tiny.write_bytes(b"\x01\x02\x03")
    for path, fmt, word in ((empty, "ibyte", "empty"), (tiny, "ishort", "less than one"),
                            (tmp_path / "nope.bin", "ibyte", "not found")):
        with pytest.raises(ValueError) as excinfo:
            IqReader(path, fmt, FS_HZ)
        assert word in _one_line_value_error(excinfo)
    with pytest.raises(ValueError, match="not found"):
        open_iq(tmp_path / "nope.bin")


def test_reading_a_big_file_never_holds_it_in_memory(tmp_path):
    size_bytes = 200 * 1024 * 1024
    path = tmp_path / "big.bin"
    with open(path, "wb") as f:
        f.truncate(size_bytes)                 # sparse: cheap to make, 100 Mi ibyte samples of zero
        f.seek(size_bytes // 2)
        f.write(struct.pack("<2b", 5, -7))    # a marker in the middle, to show the data really is read
    chunk_samples = 1 << 18
    r = IqReader(path, "ibyte", FS_HZ, chunk_samples=chunk_samples)
    tracemalloc.start()
    try:
        total, marker = 0, None
        for chunk in r:
            hit = np.flatnonzero(chunk)
            if hit.size:
                marker = (total + int(hit[0]), complex(chunk[hit[0]]))
            total += len(chunk)
        _, peak_bytes = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert total == size_bytes // 2
    assert marker == (size_bytes // 4, 5 - 7j), marker
    assert peak_bytes < size_bytes / 20, \
        f"peak {peak_bytes / 1e6:.1f} MB while reading a {size_bytes / 1e6:.0f} MB file chunkwise"


# --- SigMF sidecars ----------------------------------------------------------------------------------------------

def test_sidecar_round_trip_fills_format_rate_and_if(tmp_path):
    path = tmp_path / "out.bin"
    with IqWriter(path, "ishort", FS_HZ, if_hz=-1250.0, scale=800.0, metadata={"scenario": "static_spoof"},
                  description="spoofed", datetime_utc="2024-01-02T03:04:05.000000Z") as w:
        w.write(_noise(2000, 1.0))
    meta_path = tmp_path / "out.sigmf-meta"
    assert meta_path.exists() and not (tmp_path / "out.bin.sigmf-meta").exists()
    doc = json.loads(meta_path.read_text())
    g, cap = doc["global"], doc["captures"][0]
    assert g["core:datatype"] == "ci16_le" and g["core:sample_rate"] == FS_HZ
    assert g["core:version"] == sigmf.__specification__   # the library writes the specification it validates against
    assert g["core:recorder"] == "semperfi" and g["core:dataset"] == "out.bin" and g["core:description"] == "spoofed"
    assert g["semperfi:if_hz"] == -1250.0 and g["semperfi:scenario"] == "static_spoof"
    assert cap["core:sample_start"] == 0 and cap["core:frequency"] == L1_HZ + 1250.0
    assert cap["core:datetime"] == "2024-01-02T03:04:05.000000Z"

    r = open_iq(path)   # no format, no rate: the sidecar says
    assert (r.fmt, r.fs_hz, r.if_hz, r.n_samples) == (ISHORT, FS_HZ, -1250.0, 2000)
    assert r.sidecar.extra["scenario"] == "static_spoof"
    assert open_iq(path, fmt="ishort", fs_hz=FS_HZ, if_hz=-1250.0).n_samples == 2000, "agreeing values are fine"


def test_sidecar_named_after_the_whole_file_name_is_found(tmp_path):
    data = tmp_path / "rec.dat"
    data.write_bytes(struct.pack("<4b", 1, 2, 3, 4))
    (tmp_path / "rec.dat.sigmf-meta").write_text(json.dumps(
        {"global": {"core:datatype": "ci8", "core:sample_rate": 2e6}, "captures": [{"core:frequency": L1_HZ}]}))
    r = open_iq(data)
    assert (r.fmt, r.fs_hz, r.if_hz) == (IBYTE, 2e6, 0.0)
    assert np.array_equal(r.read(0, 2), np.array([1 + 2j, 3 + 4j], np.complex64))


def test_third_party_sidecar_if_comes_from_its_centre_frequency(tmp_path):
    data = tmp_path / "lowif.sigmf-data"
    data.write_bytes(bytes(8))
    (tmp_path / "lowif.sigmf-meta").write_text(json.dumps(
        {"global": {"core:datatype": "cf32_le", "core:sample_rate": 8e6},
         "captures": [{"core:sample_start": 0, "core:frequency": L1_HZ - 2e6}]}))
    assert open_iq(data).if_hz == pytest.approx(2e6)


@pytest.mark.parametrize("kwargs, word", [({"fs_hz": 2e6}, "sample rate"), ({"fmt": "ibyte"}, "format"),
                                          ({"if_hz": 0.0}, "IF")])
def test_values_contradicting_the_sidecar_raise(tmp_path, kwargs, word):
    path = tmp_path / "out.bin"
    with IqWriter(path, "ishort", FS_HZ, if_hz=1000.0) as w:
        w.write(np.ones(10, np.complex64))
    with pytest.raises(ValueError) as excinfo:
        open_iq(path, **kwargs)
    message = _one_line_value_error(excinfo)
    assert word in message and "out.sigmf-meta" in message, message


def test_without_sidecar_the_user_is_told_what_to_pass(tmp_path):
    path = tmp_path / "bare.bin"
    path.write_bytes(bytes(16))
    with pytest.raises(ValueError) as excinfo:
        open_iq(path, fs_hz=FS_HZ)
    assert "--format" in _one_line_value_error(excinfo)
    with pytest.raises(ValueError) as excinfo:
        open_iq(path, fmt="ibyte")
    assert "--fs" in _one_line_value_error(excinfo)
    r = open_iq(path, fmt="cfloat", fs_hz=FS_HZ)
    assert (r.fmt, r.n_samples, r.if_hz, r.sidecar) == (GR_COMPLEX, 2, 0.0, None)


GARBAGE = {
    "not json": b"this is not json {",
    "not utf-8": b"\xff\xfe\x00garbage",
    "a list": b"[1, 2, 3]",
    "no global": b'{"captures": []}',
    "global is a list": b'{"global": []}',
    "rate is a string": b'{"global": {"core:datatype": "ci8", "core:sample_rate": "fast"}}',
    "rate is negative": b'{"global": {"core:datatype": "ci8", "core:sample_rate": -4e6}}',
    "rate is a bool": b'{"global": {"core:datatype": "ci8", "core:sample_rate": true}}',
    "rate is NaN": b'{"global": {"core:datatype": "ci8", "core:sample_rate": NaN}}',
    "rate overflows": b'{"global": {"core:datatype": "ci8", "core:sample_rate": 1' + b"0" * 400 + b"}}",
    "datatype is a number": b'{"global": {"core:datatype": 8, "core:sample_rate": 4e6}}',
    "unsupported datatype": b'{"global": {"core:datatype": "cu8", "core:sample_rate": 4e6}}',
    "huge datatype": b'{"global": {"core:datatype": "' + b"c" * 500_000 + b'", "core:sample_rate": 4e6}}',
    "if is a dict": b'{"global": {"core:datatype": "ci8", "core:sample_rate": 4e6, "semperfi:if_hz": {}}}',
    "captures not a list": b'{"global": {"core:datatype": "ci8", "core:sample_rate": 4e6}, "captures": 3}',
    "frequency is a string": b'{"global": {"core:datatype": "ci8", "core:sample_rate": 4e6},'
                             b' "captures": [{"core:frequency": "L1"}]}',
    "deeply nested": b"[" * 200_000 + b"]" * 200_000,
    "nested past the library": b'{"global": {"core:datatype": "ci8", "semperfi:x": ' + b"[" * 900 + b"]" * 900 + b"}}",
    "no datatype": b'{"global": {"core:sample_rate": 4e6}}',
    "a key SigMF lacks": b'{"global": {"core:datatype": "ci8"}, "' + b"k" * 100_000 + b'": 1}',
    "300 000 captures": b'{"global": {"core:datatype": "ci8"}, "captures": [' + b",".join([b"{}"] * 300_000) + b"]}",
    "too big": b'{"global": {"core:description": "' + b"x" * (MAX_META_BYTES + 10) + b'"}}',
}


@pytest.mark.parametrize("name", list(GARBAGE))
def test_garbage_sidecar_is_one_value_error_line(tmp_path, name):
    path = tmp_path / "g.bin"
    path.write_bytes(bytes(64))
    (tmp_path / "g.sigmf-meta").write_bytes(GARBAGE[name])
    with pytest.raises(ValueError) as excinfo:
        open_iq(path, fmt="ibyte", fs_hz=4e6)
    message = _one_line_value_error(excinfo)
    assert "g.sigmf-meta" in message, f"{name}: the message should name the sidecar: {message!r}"
    assert len(message) < 300, f"{name}: message too long: {message[:120]!r}..."


def test_our_sidecar_passes_the_sigmf_librarys_own_validator(tmp_path):
    """The reference validator, as its command line runs it, with undeclared namespaces an error rather than the
    library's warning (ours must be declared)."""
    from sigmf.validate import main as sigmf_validate
    path = tmp_path / "out.bin"
    with IqWriter(path, "ishort", FS_HZ, if_hz=-1250.0, metadata={"run": {"seed": 3}},
                  datetime_utc=datetime.datetime(2024, 1, 2, 3, 4, 5)) as w:
        w.write(_noise(100, 1.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sigmf_validate((str(tmp_path / "out.sigmf-meta"),))   # SystemExit(1) if it finds anything wrong


def test_a_sidecar_breaking_the_sigmf_schema_is_one_bad_input_line(tmp_path):
    path = tmp_path / "m.sigmf-meta"
    path.write_text(json.dumps({"global": {"core:datatype": "ci8", "core:author": 3}}))
    with pytest.raises(BadInput) as excinfo:
        read_sigmf_meta(path)
    assert _one_line_value_error(excinfo).endswith(
        "m.sigmf-meta: not valid SigMF ($.global['core:author']: 3 is not of type 'string')")


def test_read_sigmf_meta_direct(tmp_path):
    path = tmp_path / "m.sigmf-meta"
    path.write_text(json.dumps({"global": {"core:datatype": "cf32_le", "core:sample_rate": 1e6,
                                           "semperfi:if_hz": 5.0, "semperfi:run": {"seed": 3}}}))
    meta = read_sigmf_meta(path)
    assert (meta.datatype, meta.sample_rate_hz, meta.if_hz, meta.extra) == ("cf32_le", 1e6, 5.0, {"run": {"seed": 3}})
    assert meta.implied_if_hz() == 5.0


# --- real-valued IF samples, SigMF datatypes, spectral inversion ---------------------------------------------------

from semperfi.iq import encode_samples, with_iq_swap  # noqa: E402
from semperfi.iq.formats import FORMATS, decode_items  # noqa: E402


@pytest.mark.parametrize("fmt", [f for f in FORMATS if not f.bits], ids=lambda f: f.name)
def test_every_format_round_trips_within_half_a_step(fmt):
    x = _noise(500, 20.0).astype(np.complex64)
    items, clipped = encode_samples(x, fmt)
    y = decode_items(items, fmt)
    want = x if fmt.is_complex else x.real.astype(np.complex64)
    # Integers: rounding (0.5) plus, for unsigned, mid-scale 127.5 stored as 128 (0.5 more).
    tol = (1.01 if fmt.offset else 0.51) if fmt.is_integer else 1e-3
    err = np.abs((y - want).view(np.float32)).max()   # per I or Q value
    assert clipped == 0 and err < tol, f"{fmt.name}: error {err:.3f}"
    assert len(items) * fmt.item_dtype.itemsize == len(x) * fmt.bytes_per_sample


def test_real_byte_file_is_x_plus_0j_at_its_if(tmp_path):
    path = tmp_path / "real.bin"
    np.array([1, -2, 3, -128, 127], dtype=np.int8).tofile(path)
    r = open_iq(path, "byte", 12e6, 3e6)
    assert np.array_equal(r.read(0, 5), np.array([1, -2, 3, -128, 127], dtype=np.complex64))
    assert (len(r), r.if_hz) == (5, 3e6)


def test_iq_swap_reads_q_first_and_writes_it_back_the_same(tmp_path):
    path = tmp_path / "swapped.bin"
    np.array([2, 1, -4, 3], dtype=np.int16).tofile(path)   # Q, I, Q, I
    fmt = with_iq_swap("ishort")
    assert np.array_equal(IqReader(path, fmt, 4e6).read(0, 2), np.array([1 + 2j, 3 - 4j], dtype=np.complex64))
    items, _ = encode_samples(np.array([1 + 2j, 3 - 4j], dtype=np.complex64), fmt)
    assert items.tolist() == [2, 1, -4, 3]
    with pytest.raises(ValueError, match="real samples"):
        with_iq_swap("byte")


def test_foreign_sigmf_recording_with_ri16_and_rf_centre_frequency(tmp_path):
    """A SigMF recording by another tool: real int16 samples, L1 placed by core:frequency, not by our namespace."""
    import json
    data = tmp_path / "capture.sigmf-data"
    np.arange(-8, 8, dtype="<i2").tofile(data)
    meta = {"global": {"core:datatype": "ri16_le", "core:sample_rate": 16.368e6, "core:version": "1.0.0"},
            "captures": [{"core:sample_start": 0, "core:frequency": 1575.42e6 - 4.092e6}], "annotations": []}
    (tmp_path / "capture.sigmf-meta").write_text(json.dumps(meta))
    r = open_iq(data)
    assert (r.fmt.name, r.fs_hz, r.if_hz) == ("short", 16.368e6, 4.092e6)
    assert np.array_equal(r.read(0, 3), np.array([-8, -7, -6], dtype=np.complex64))


# --- packed 2- and 4-bit samples -----------------------------------------------------------------------------------

PACKED_BYTES = np.array([0b00011011, 0xF1], dtype=np.uint8)
PACKED_VALUES = {   # by hand from the bit layouts in semperfi.iq.formats
    "real2": [-1, -3, 3, 1, 3, 1, -1, -1],              # two's complement v -> 2v+1, lowest bits first
    "iq2": [-1 - 3j, 3 + 1j, 3 + 1j, -1 - 1j],
    "real2sm": [1, 3, -1, -3, -3, -3, 1, 3],            # sign|magnitude, highest bits first
    "iq2sm": [1 + 3j, -1 - 3j, -3 - 3j, 1 + 3j],
    "real4": [3, -9, -1, 3],                            # nibbles, high first: 0x1 -> 3, 0xB = -5 -> -9
    "iq4": [3 - 9j, -1 + 3j],
}


@pytest.mark.parametrize("name", sorted(PACKED_VALUES))
def test_packed_values_decode_as_their_front_ends_define_them(name):
    assert decode_items(PACKED_BYTES, format_by_name(name)).tolist() == PACKED_VALUES[name]


@pytest.mark.parametrize("name", ["real2", "iq2sm", "iq4"])
def test_packed_files_read_at_any_sample_in_chunks_and_from_a_pipe(tmp_path, name):
    import io
    from semperfi.iq.source import open_source
    fmt = format_by_name(name)
    raw = np.random.default_rng(7).integers(0, 256, 1001, dtype=np.uint8)
    path = tmp_path / "p.bin"
    raw.tofile(path)
    whole = decode_items(raw, fmt)
    reader = IqReader(path, fmt, 4e6, chunk_samples=333, if_hz=0.0 if fmt.is_complex else 1e6)
    assert (reader.n_samples, reader.truncated_bytes) == (1001 * fmt.samples_per_block, 0)
    assert np.array_equal(reader.read(5, 17), whole[5:22]) and np.array_equal(reader.read(3, 1), whole[3:4])
    assert np.array_equal(np.concatenate(list(reader)), whole)
    pipe = open_source("-", fmt, 4e6, 0.0 if fmt.is_complex else 1e6, skip_s=7 / 4e6, stdin=io.BytesIO(raw.tobytes()))
    assert np.array_equal(pipe.take(50), whole[7:57])
    with pytest.raises(ValueError, match="packed"):
        encode_samples(whole, fmt)


@pytest.mark.parametrize("name", ["real2sm", "iq2"])
def test_two_bit_recording_of_gps_acquires_at_the_truths_code_phase(tmp_path, name):
    """A simulated scene quantised to 2 bits as a low-bit front end does (thresholds at one sigma), real at an IF or
    complex: the satellites come out at the simulator's code phases."""
    from semperfi.receiver.acquisition import DopplerGrid, acquire
    from semperfi.sim.run import simulate_to_file
    from semperfi.sim.scenario import load_scenario
    from semperfi.sim.truth import read_signal_truth, truth_paths

    fs, if_hz = 4e6, 1.25e6
    cfg = load_scenario(None, [f"signal.fs_hz={fs}", "time.duration_s=0.05", 'signal.format="gr_complex"',
                               "constellation.max_satellites=6", "constellation.cn0_dbhz=50"])
    simulate_to_file(cfg, tmp_path / "s.bin")
    x = IqReader(tmp_path / "s.bin", "gr_complex", fs).read(0, int(fs * 0.05))
    fmt = format_by_name(name)
    if not fmt.is_complex:
        x = np.sqrt(2) * (x * np.exp(2j * np.pi * if_hz * np.arange(len(x)) / fs)).real
    levels = np.stack([x.real, x.imag], 1).ravel() if fmt.is_complex else x.real
    sigma = levels.std()
    negative, big = levels < 0, np.abs(levels) > sigma
    fields = (negative.astype(np.uint8) << 1) | big if fmt.sign_magnitude else \
        np.where(negative, np.where(big, 2, 3), np.where(big, 1, 0)).astype(np.uint8)   # v in {-2,-1,0,1}
    fields = fields.reshape(-1, 4)
    order = [3, 2, 1, 0] if fmt.msb_first else [0, 1, 2, 3]
    packed = sum(fields[:, k].astype(np.uint8) << (2 * order[k]) for k in range(4)).astype(np.uint8)
    packed.tofile(tmp_path / "p.bin")
    samples = IqReader(tmp_path / "p.bin", fmt, fs, if_hz=0.0 if fmt.is_complex else if_hz).read(0, len(x))
    cafs = acquire(samples, fs, range(1, 33), DopplerGrid(0.0, 5000.0, 250.0), 0.0 if fmt.is_complex else if_hz,
                   coherent_ms=5, noncoherent=4)
    truth = {int(r["prn"]): r for r in read_signal_truth(truth_paths(tmp_path / "s.bin")["signals.csv"])
             if r["t_rx_s"] == 0.0}
    found = {prn: c.best for prn, c in cafs.items() if c.best is not None}
    assert set(truth) <= set(found), (sorted(truth), sorted(found))
    for prn, r in truth.items():
        d = (found[prn].code_phase_chips - r["code_phase_chips"] + 511.5) % 1023 - 511.5
        assert abs(d) < 0.3, (prn, d)
        assert abs(found[prn].doppler_hz - r["doppler_hz"]) < 200.0

"""Navigation decoding of one channel: what a satellite broadcasts is found in the bit stream, whatever the start,
polarity, chunking or noise, and an attacker's bits (false preambles, splices, garbage) never become data."""

import dataclasses
import gc
import tracemalloc

import numpy as np
import pytest

from semperfi.gps import lnav
from semperfi.gps.ephemeris import UtcParams
from semperfi.gps.time import GpsTime
from semperfi.receiver.navigation import MAX_BUFFER_BITS, AssistedNav, NavDecoder, SubframeEvent
from semperfi.sim.constellation import DEFAULT_IONO, synthesize

WEEK = 2300
WEEK_S = 604800
START = GpsTime(WEEK, 345600.0)
CONSTELLATION = synthesize(START)
PRN = 5
EPH = CONSTELLATION[PRN]
IONO = DEFAULT_IONO
UTC = UtcParams(a0_s=2.79396772385e-09, a1_s_s=7.99360577730e-15, tot_s=147456, wnt=WEEK % 256, delta_t_ls_s=18,
                wn_lsf=137, dn=7, delta_t_lsf_s=18)


def page18_k(near_k: int) -> int:
    """The subframe number (of the week) of the subframe 4 page 18 at or after near_k."""
    k = near_k
    while not (k % 5 == 3 and (k // 5) % 25 == 17):
        k += 1
    return k


K18 = page18_k(int(START.tow_s) // 6)          # subframe 4 page 18 (ionosphere, UTC)


def stream(k_first: int, n: int, eph=EPH, iono=IONO, utc=UTC) -> np.ndarray:
    """Bits of subframes k_first .. k_first + n - 1, as the satellite sends them."""
    return np.concatenate([lnav.subframe_bits(k, eph, iono, utc, CONSTELLATION) for k in range(k_first, k_first + n)])


def soft(bits: np.ndarray, inverted: bool = False, amplitude: float = 1800.0, sigma: float = 250.0,
         seed: int = 0) -> np.ndarray:
    """Tracking's soft bits: +A for a 0 bit, -A for a 1 (both negated when the Costas loop sits at 180 deg), noise."""
    values = amplitude * (1.0 - 2.0 * bits.astype(np.float64))
    if inverted:
        values = -values
    return values + np.random.default_rng(seed).normal(0.0, sigma, bits.size)


def expected_events(k_first: int, n_bits: int, offset: int, first_index: int) -> list[tuple]:
    """(subframe id, page, start bit index, t_sv_start_s) of every subframe wholly inside the delivered bits
    stream(k_first, ...)[offset:offset + n_bits], delivered from channel bit index first_index."""
    out = []
    for j in range(n_bits // 300 + 2):
        begin = 300 * j - offset
        if begin >= 0 and begin + 300 <= n_bits:
            k = (k_first + j) % 100800
            page = (k // 5) % 25 + 1 if k % 5 >= 3 else 0
            out.append((k % 5 + 1, page, first_index + begin, float(6 * k % WEEK_S)))
    return out


def summary(events) -> list[tuple]:
    return [(e.subframe_id, e.page, e.start_bit_index, e.t_sv_start_s) for e in events]


def push_in_chunks(decoder: NavDecoder, values: np.ndarray, first_index: int, sizes) -> list[SubframeEvent]:
    events, at, sizes = [], 0, iter(sizes)
    while at < values.size:
        n = next(sizes)
        events += decoder.push_bits(values[at:at + n], first_index + at)
        assert decoder.buffered_bits <= MAX_BUFFER_BITS, f"buffer grew to {decoder.buffered_bits} bits"
        at += n
    return events


def quantized_iono_utc(iono=IONO, utc=UTC):
    return lnav.iono_utc_from_subframe(lnav.decode_subframe(lnav.subframe_bits(K18, EPH, iono, utc, CONSTELLATION)))


# ------------------------------------------------------------------------------------------------- decoding


@pytest.mark.parametrize("inverted", [False, True], ids=["upright", "inverted"])
def test_mid_subframe_start_decodes_every_complete_subframe(inverted):
    k_first, offset, first_index = K18 - 2, 137, 4242
    bits = stream(k_first, 13)[offset:-100]              # starts 137 bits into a subframe, ends inside one
    decoder = NavDecoder(PRN, full_week_hint=WEEK)
    events = decoder.push_bits(soft(bits, inverted), first_index)

    expected = expected_events(k_first, bits.size, offset, first_index)
    assert len(expected) == 11
    assert summary(events) == expected
    assert [e.parity_errors for e in events] == [0] * 11
    assert not any(e.tow_inconsistent for e in events)
    assert all(e.inverted == inverted and e.prn == PRN for e in events)
    assert [e.tow_count_next for e in events] == [(k + 1) for k in range(k_first + 1, k_first + 12)]

    assert decoder.ephemeris == lnav.quantize_ephemeris(EPH) == EPH
    iono, utc = quantized_iono_utc()
    assert (decoder.iono, decoder.utc) == (iono, utc)
    assert np.allclose(decoder.iono.alpha, IONO.alpha, rtol=0, atol=2.0 ** -30 * 4) and decoder.utc.a0_s == \
        pytest.approx(UTC.a0_s, abs=2.0 ** -30)

    # Transmit time at any later bit, from the anchor: subframe k_first starts at SV time 6 k_first.
    last = events[-1]
    assert decoder.time_anchor == (last.start_bit_index, last.t_sv_start_s)
    bit = first_index + bits.size + 777
    assert decoder.transmit_time_s(bit) == pytest.approx(6 * k_first + (bit - first_index + offset) * 0.020,
                                                         abs=1e-9)


def test_rinex_ephemeris_decodes_to_its_broadcast_quantization(brdc_path):
    from semperfi.iq.rinex import read_rinex_nav
    nav = read_rinex_nav(brdc_path)
    eph = next(e for e in nav.ephemerides if e.prn == 7 and e.health == 0)
    k_first = page18_k(int(eph.toe_s) // 6) - 3
    bits = stream(k_first, 12, eph=eph, iono=nav.iono, utc=nav.utc)[51:]
    decoder = NavDecoder(7, full_week_hint=eph.week)
    events = decoder.push_bits(soft(bits, inverted=True, seed=3), 0)
    assert summary(events) == expected_events(k_first, bits.size, 51, 0)
    assert all(e.parity_errors == 0 for e in events)
    assert decoder.ephemeris == lnav.quantize_ephemeris(eph)
    assert decoder.ephemeris != eph          # the broadcast is quantized, the RINEX values are not
    assert (decoder.iono, decoder.utc) == quantized_iono_utc(nav.iono, nav.utc)


def test_polarity_flip_at_a_subframe_boundary_loses_nothing():
    k_first, offset = K18 - 2, 40
    bits = stream(k_first, 12)[offset:]
    values = soft(bits)
    flip_at = 300 * 5 - offset                      # a cycle slip between two subframes
    values[flip_at:] *= -1
    decoder = NavDecoder(PRN, WEEK)
    events = decoder.push_bits(values, 0)
    assert summary(events) == expected_events(k_first, bits.size, offset, 0)
    assert [e.parity_errors for e in events] == [0] * len(events)
    assert [e.inverted for e in events] == [e.start_bit_index >= flip_at for e in events]
    assert decoder.ephemeris == EPH and decoder.iono is not None


def test_cycle_slip_inside_a_subframe_costs_only_that_subframe():
    k_first, offset = K18 - 2, 40
    bits = stream(k_first, 16)[offset:]
    values = soft(bits)
    damaged_start = 300 * 4 - offset                # subframe k_first + 4 = subframe 1 of the next frame
    values[damaged_start + 130:] *= -1              # slip in its word 5
    decoder = NavDecoder(PRN, WEEK)
    events = decoder.push_bits(values, 0)
    assert summary(events) == expected_events(k_first, bits.size, offset, 0)
    errors = {e.start_bit_index: e.parity_errors for e in events}
    assert errors.pop(damaged_start) >= 1
    assert set(errors.values()) == {0}, errors
    assert decoder.ephemeris == EPH                 # from the next frame's subframe 1


@pytest.mark.parametrize("flips, late", [((25,), False), ((2, 7), False), ((25, 41), True)],
                         ids=["a slip in the TLM", "bits garbled in the TLM", "slips in the TLM and the HOW"])
def test_a_broken_second_head_costs_the_channel_no_time_while_its_how_holds(flips, late):
    """A spoofer's carrier stepping beside the tracked one (a time push's start) slips the Costas loop by half a
    cycle and garbles a few bits; inside the head (TLM and HOW) of the second subframe a fresh channel sees, that
    breaks the pair that would confirm the first. While the second head's HOW holds (its own parity, whatever the TLM
    before it says), it confirms the whole first head: the channel has its time when the second head is whole, as
    without the slip. With the HOW broken too, the first head is confirmed by the third, two subframes on, as soon
    as that one is whole. flips: where the bits' sign turns (a slip; two close together: garbled bits)."""
    k_first, offset = K18 - 2, 40
    bits = stream(k_first, 6)[offset:]
    values = soft(bits)
    first = 300 - offset                            # the first whole subframe
    for at in flips:
        values[first + 300 + at:] *= -1
    decoder = NavDecoder(PRN, WEEK)
    timed_at = first + (600 if late else 300) + 60
    events = decoder.push_bits(values[:timed_at - 1], 0)
    assert decoder.time_anchor is None
    events += decoder.push_bits(values[timed_at - 1:timed_at], timed_at - 1)
    assert decoder.time_anchor == (first, float(6 * (k_first + 1) % WEEK_S))
    events += decoder.push_bits(values[timed_at:], timed_at)
    good = {(e.start_bit_index, e.t_sv_start_s) for e in events if e.parity_errors == 0}
    assert good >= {(first + 300 * j, float(6 * (k_first + 1 + j) % WEEK_S)) for j in (0, 2, 3)}, good
    assert first + 300 not in {b for b, _ in good}, "the damaged subframe was taken"


@pytest.mark.parametrize("sizes", [[1], [7], [50], [299], [301], [4096], "random"])
def test_chunking_does_not_change_what_is_decoded(sizes):
    k_first, offset = K18 - 2, 211
    bits = stream(k_first, 14)[offset:-33]
    values = soft(bits, inverted=True, seed=7)
    whole = NavDecoder(PRN, WEEK)
    reference = whole.push_bits(values, 1000)
    assert len(reference) == 12 and whole.ephemeris == EPH

    if sizes == "random":
        sizes = np.random.default_rng(11).integers(1, 400, size=values.size)
    else:
        sizes = sizes * values.size
    chunked = NavDecoder(PRN, WEEK)
    events = push_in_chunks(chunked, values, 1000, sizes)
    assert events == reference
    assert (chunked.ephemeris, chunked.iono, chunked.utc, chunked.time_anchor) == \
        (whole.ephemeris, whole.iono, whole.utc, whole.time_anchor)


def test_subframes_across_the_end_of_the_week():
    k_first = 100800 - 7
    bits = np.concatenate([lnav.subframe_bits(k, EPH, IONO, UTC, CONSTELLATION) for k in range(k_first, k_first + 14)])
    decoder = NavDecoder(PRN, WEEK)
    events = decoder.push_bits(soft(bits[99:]), 0)
    assert summary(events) == expected_events(k_first, bits.size - 99, 99, 0)
    assert [e.t_sv_start_s for e in events][5:8] == [604794.0, 0.0, 6.0]
    assert not any(e.tow_inconsistent or e.parity_errors for e in events)
    assert decoder.transmit_time_s(events[5].start_bit_index + 400) == pytest.approx(2.0)


def nonstandard_stream(k_first: int, n: int, word10_end: tuple[int, int]) -> np.ndarray:
    """Like stream(), but every word 10 ends in word10_end instead of 00 (its t bits chosen for that; a transmitter
    breaking IS-GPS-200 20.3.5.2), so each TLM must be checked with D29*, D30* that are not 0, 0."""
    words, d29, d30 = [], 0, 0
    for k in range(k_first, k_first + n):
        sources = lnav.decode_subframe(lnav.subframe_bits(k, EPH, IONO, UTC, CONSTELLATION)).data_bits.reshape(10, 24)
        for i, source in enumerate(sources):
            source = source.copy()
            if i == 1:
                source = lnav._solve_t(source, d29, d30)         # the HOW still ends in 00
            if i == 9:
                for t in ((0, 0), (0, 1), (1, 0), (1, 1)):
                    source[22:24] = t
                    if tuple(lnav._encode_word(source, d29, d30)[28:30]) == word10_end:
                        break
            word = lnav._encode_word(source, d29, d30)
            words.append(word)
            d29, d30 = int(word[28]), int(word[29])
    bits = np.concatenate(words)
    assert all(tuple(bits[300 * j + 298:300 * j + 300]) == word10_end for j in range(n))
    return bits


@pytest.mark.parametrize("word10_end", [(1, 0), (0, 1), (1, 1)])
def test_true_d29_d30_of_the_word_before_each_subframe_are_used(word10_end):
    k_first, offset = K18 - 2, 290                  # starts 10 bits before a TLM: its D29*, D30* are in the stream
    bits = nonstandard_stream(k_first, 12, word10_end)[offset:]
    decoder = NavDecoder(PRN, WEEK)
    events = decoder.push_bits(soft(bits, seed=8), 0)
    assert summary(events) == expected_events(k_first, bits.size, offset, 0)
    assert [e.parity_errors for e in events] == [0] * len(events)
    assert decoder.ephemeris == EPH and (decoder.iono, decoder.utc) == quantized_iono_utc()


# ------------------------------------------------------------------------------------------------- gaps


@pytest.mark.parametrize("gap", [1, 300, 413])
def test_gap_in_bit_count_resynchronises_without_wrong_events(gap):
    k_first, offset = K18 - 2, 50
    bits = stream(k_first, 16)[offset:]
    values = soft(bits, seed=5)
    cut = 1000
    decoder = NavDecoder(PRN, WEEK)
    events = decoder.push_bits(values[:cut], 0)
    events += decoder.push_bits(values[cut + gap:], cut + gap)    # the bits in between never arrive

    def inside(start):
        return start + 300 <= cut or start >= cut + gap

    expected = [e for e in expected_events(k_first, bits.size, offset, 0) if inside(e[2])]
    assert summary(events) == expected
    assert all(e.parity_errors == 0 and not e.tow_inconsistent for e in events)
    assert decoder.ephemeris == EPH


def test_bit_count_restarting_means_a_new_time_scale():
    decoder = NavDecoder(PRN, WEEK)
    first = decoder.push_bits(soft(stream(K18, 4)[10:]), 5000)
    assert len(first) == 3
    k_later = K18 + 400                              # 40 min later, after tracking re-locked: bit count from 0
    bits = stream(k_later, 4)[20:]
    events = decoder.push_bits(soft(bits), 0)
    assert summary(events) == expected_events(k_later, bits.size, 20, 0)
    assert not any(e.tow_inconsistent for e in events)
    assert decoder.time_anchor == (events[-1].start_bit_index, events[-1].t_sv_start_s)


# ------------------------------------------------------------------------------------------------- attacks


def crafted_subframe(k: int, fake_tow_next: int, fake_id: int, preamble: bool = True) -> np.ndarray:
    """Subframe k whose words 3-4 hold a TLM (with a preamble, or without) and a HOW that pass parity."""
    for t in range(4):
        data = np.zeros(192, dtype=np.uint8)
        if preamble:
            data[:8] = lnav.PREAMBLE
        data[24:41] = [(fake_tow_next >> (16 - i)) & 1 for i in range(17)]
        data[43:46] = [(fake_id >> (2 - i)) & 1 for i in range(3)]
        data[46:48] = (t >> 1, t & 1)
        bits = lnav.encode_subframe(k % 5 + 1, (k + 1) % 100800, data)
        if not bits[118] and not bits[119]:          # the fake HOW ends in 00, like a real one
            break
    fake = bits[60:120]
    assert np.array_equal(fake[:8], lnav.PREAMBLE) == preamble
    assert lnav.check_parity(fake[:30], 0, 0)[0] and lnav.check_parity(fake[30:], fake[28], fake[29])[0]
    return bits


@pytest.mark.parametrize("where", ["before_sync", "in_sync"])
def test_false_preamble_in_the_data_never_becomes_a_subframe(where):
    k_crafted = K18 + 1                              # a subframe 5; its words 3-4 look like TLM + HOW
    k_first = k_crafted if where == "before_sync" else k_crafted - 3
    bits = []
    for k in range(k_first, k_first + 14):
        bits.append(crafted_subframe(k, k_crafted + 2, 2) if k in (k_crafted, k_crafted + 5)
                    else lnav.subframe_bits(k, EPH, IONO, UTC, CONSTELLATION))
    offset = 30                                     # before_sync: the false preamble is the first one seen
    bits = np.concatenate(bits)[offset:]
    decoder = NavDecoder(PRN, WEEK)
    events = decoder.push_bits(soft(bits, seed=2), 0)
    expected = [e[:1] + e[2:] for e in expected_events(k_first, bits.size, offset, 0)]
    assert [e[:1] + e[2:] for e in summary(events)] == expected   # page aside: the crafted pages carry SV ID 11
    assert all(e.start_bit_index % 300 == 300 - offset for e in events)
    assert all(e.parity_errors == 0 and not e.tow_inconsistent for e in events)
    assert decoder.ephemeris == EPH


def test_flipped_bit_is_reported_and_never_used():
    k_first, offset = K18 + 1, 150                  # inside a subframe 5; then subframes 1, 2, 3 of a frame
    bits = stream(k_first, 11)[offset:]
    values = soft(bits, seed=9)
    sf2_start = 2 * 300 - offset                    # the first subframe 2
    values[sf2_start + 4 * 30 + 6] *= -1            # one data bit of its word 5 (part of M0)
    preamble_hit = 5 * 300 - offset                 # the first subframe 5: a bit of its preamble
    values[preamble_hit + 3] *= -1

    decoder = NavDecoder(PRN, WEEK)
    events = []
    for at in range(0, values.size, 50):
        events += decoder.push_bits(values[at:at + 50], at)
        assert decoder.ephemeris in (None, EPH), "a corrupted subframe 2 made an ephemeris"
        if at + 50 < 7 * 300 - offset:              # until the next frame's subframe 2 is complete
            assert decoder.ephemeris is None
    assert summary(events) == expected_events(k_first, bits.size, offset, 0)
    errors = {e.start_bit_index: e.parity_errors for e in events}
    assert errors.pop(sf2_start) == 1 and errors.pop(preamble_hit) == 1
    assert set(errors.values()) == {0}
    assert decoder.ephemeris == EPH                 # subframe 1 and 3 of frame one, 2 of frame two: one IODE


def test_two_damaged_subframes_in_a_row_are_reported_once_each():
    k_first, offset = K18 - 2, 20
    bits = stream(k_first, 14)[offset:]
    values = soft(bits, seed=6)
    damaged = [300 * 6 - offset, 300 * 7 - offset]   # two in a row: the decoder drops sync and searches again
    for start in damaged:
        values[start + 5 * 30 + 11] *= -1
    decoder = NavDecoder(PRN, WEEK)
    events = push_in_chunks(decoder, values, 0, [100] * values.size)
    assert summary(events) == expected_events(k_first, bits.size, offset, 0)
    assert {e.start_bit_index for e in events if e.parity_errors} == set(damaged)
    assert decoder.ephemeris == EPH and decoder.in_sync


def test_an_orbit_no_gps_satellite_flies_is_not_taken():
    absurd = lnav.quantize_ephemeris(dataclasses.replace(EPH, sqrt_a_sqrt_m=3000.0))   # a 9000 km orbit radius
    bits = stream(K18 - 2, 12, eph=absurd)[5:]
    decoder = NavDecoder(PRN, WEEK)
    events = decoder.push_bits(soft(bits), 0)
    assert len(events) == 11 and all(e.parity_errors == 0 for e in events)
    assert decoder.ephemeris is None and decoder.iono is not None


def other_upload():
    """A later upload of the same satellite: new IODE/IODC, toe two hours on, a different clock."""
    return lnav.quantize_ephemeris(dataclasses.replace(
        EPH, toe_s=EPH.toe_s + 7200, toc_s=EPH.toc_s + 7200, iode=(EPH.iode + 1) % 256, iodc=(EPH.iodc + 1) % 1024,
        af0_s=EPH.af0_s + 1e-6, m0_rad=EPH.m0_rad + 0.1))


def test_new_iode_replaces_the_ephemeris_only_when_its_set_is_complete():
    new = other_upload()
    # a subframe 5, then frame one (old upload), frames two, three (new)
    k_first = 5 * (int(START.tow_s) // 30) - 1
    bits = np.concatenate([lnav.subframe_bits(k, EPH if k < k_first + 6 else new, IONO, UTC, CONSTELLATION)
                           for k in range(k_first, k_first + 14)])[100:]
    values = soft(bits, seed=4)
    new_sf2 = 7 * 300 - 100                          # frame two's subframe 2: one bit flipped
    values[new_sf2 + 200] *= -1
    decoder = NavDecoder(PRN, WEEK)
    seen = []
    for at in range(0, values.size, 300):
        for e in decoder.push_bits(values[at:at + 300], at):
            seen.append((e.subframe_id, e.parity_errors, decoder.ephemeris))
    assert [(sf, err) for sf, err, _ in seen] == [(1, 0), (2, 0), (3, 0), (4, 0), (5, 0), (1, 0), (2, 1), (3, 0),
                                                 (4, 0), (5, 0), (1, 0), (2, 0), (3, 0)]
    # Old set from the third subframe on; the new upload's 1 and 3 without its 2 change nothing; its 2 completes it.
    assert [eph for _, _, eph in seen] == [None, None] + [EPH] * 9 + [new, new]


def test_new_iode_waits_for_its_own_subframes():
    new = other_upload()
    k_first = 5 * (int(START.tow_s) // 30)
    bits = np.concatenate([lnav.subframe_bits(k, EPH if k < k_first + 5 else new, IONO, UTC, CONSTELLATION)
                           for k in range(k_first - 1, k_first + 10)])[100:]
    decoder = NavDecoder(PRN, WEEK)
    seen = []
    for at in range(0, bits.size, 300):
        for e in decoder.push_bits(soft(bits[at:at + 300], seed=at), at):
            seen.append((e.subframe_id, decoder.ephemeris))
    assert [sf for sf, _ in seen] == [1, 2, 3, 4, 5, 1, 2, 3, 4, 5]
    assert [eph for _, eph in seen] == [None, None, EPH, EPH, EPH, EPH, EPH, new, new, new]


@pytest.mark.parametrize("misalign", [0, 60, 123])    # 60: word-aligned, so B's words pass parity in A's frame
def test_spliced_stream_with_another_time_is_flagged(misalign):
    k_a, k_b = K18 - 3, K18 - 3 + 7 + 1003          # B: the same satellite 100 min later (or a replay)
    b_eph = other_upload()
    a = stream(k_a, 7)[10:]                           # a's subframes start at 290 + 300 j
    b = stream(k_b, 16, eph=b_eph)[misalign:]
    decoder = NavDecoder(PRN, WEEK)
    events_a = decoder.push_bits(soft(a), 0)
    assert len(events_a) == 6 and decoder.ephemeris == EPH
    anchor_a = decoder.time_anchor
    assert anchor_a == (events_a[-1].start_bit_index, float(6 * (k_a + 6) % WEEK_S))

    events_b = []
    for at in range(0, b.size, 100):
        new = decoder.push_bits(soft(b[at:at + 100], seed=at), a.size + at)
        events_b += new
        good = [e for e in events_b if e.parity_errors == 0]
        if len(good) == 1:
            assert decoder.time_anchor == anchor_a, "one subframe with a jumping TOW moved the time anchor"
    good = [e for e in events_b if e.parity_errors == 0]
    assert good[0].tow_inconsistent and good[1].tow_inconsistent
    assert not any(e.tow_inconsistent for e in good[2:])
    b_start = a.size + (300 - misalign) % 300         # channel bit index of B's first whole subframe
    assert [(e.start_bit_index, e.t_sv_start_s) for e in good] == \
        [(s, float(6 * (k_b + (s - a.size + misalign) // 300) % WEEK_S))
         for s in range(b_start, b_start + 300 * len(good), 300)]
    assert decoder.time_anchor == (good[-1].start_bit_index, good[-1].t_sv_start_s)
    assert decoder.ephemeris == b_eph                 # from B's subframes after the re-anchor only


def test_word_aligned_slip_is_not_taken_for_subframes():
    """After a splice two words off the frame, every word passes parity in the old frame timing, and the words
    where TLM and HOW should be carry a HOW with the TOW and ID the old anchor expects, but no preamble."""
    k_a = K18 - 3
    a = stream(k_a, 7)[10:]                           # ends where A's next subframe (k_a + 7) would start
    k_b = k_a + 7 + 1003
    b = []
    for j in range(16):
        k = k_b + j
        if j < 3:                                     # what the old timing expects at its subframes k_a + 7 + j
            expected_k = k_a + 7 + j
            b.append(crafted_subframe(k, expected_k + 1, expected_k % 5 + 1, preamble=False))
        else:
            b.append(lnav.subframe_bits(k, EPH, IONO, UTC, CONSTELLATION))
    b = np.concatenate(b)[60:]
    decoder = NavDecoder(PRN, WEEK)
    decoder.push_bits(soft(a), 0)
    events = decoder.push_bits(soft(b, seed=1), a.size)
    bad = [e for e in events if e.parity_errors]
    good = [e for e in events if not e.parity_errors]
    assert [e.start_bit_index for e in bad] == [a.size, a.size + 300], "a TLM without preamble passed"
    b_start = a.size + 240                           # B's first whole subframe
    assert [(e.start_bit_index, e.t_sv_start_s) for e in good] == \
        [(b_start + 300 * j, float(6 * (k_b + 1 + j) % WEEK_S)) for j in range(len(good))]
    assert len(good) == 15 and [e.tow_inconsistent for e in good[:3]] == [True, True, False]


def test_spliced_subframes_do_not_feed_the_ephemeris():
    k_a = K18 - 9                                     # A: the end of a subframe 5, two whole frames
    k_b = 5 * ((k_a + 2000) // 5)                     # B: from subframe 1, another time, another upload
    b_eph = other_upload()
    a = stream(k_a, 11)[10:]
    decoder = NavDecoder(PRN, WEEK)
    assert len(decoder.push_bits(soft(a), 0)) == 10 and decoder.ephemeris == EPH
    seen = []
    b = stream(k_b, 8, eph=b_eph)
    for at in range(0, b.size, 300):
        for e in decoder.push_bits(soft(b[at:at + 300], seed=at), a.size + at):
            seen.append((e.subframe_id, e.tow_inconsistent, decoder.ephemeris))
    assert [(sf, flag) for sf, flag, _ in seen] == [(1, True), (2, True), (3, False), (4, False), (5, False),
                                                   (1, False), (2, False), (3, False)]
    # B's flagged 1 and 2 are not used, so B's 3 cannot complete a set with them: A's ephemeris stays until
    # B's second frame brings a 1 and a 2 of B's upload.
    assert [eph for _, _, eph in seen] == [EPH] * 6 + [b_eph] * 2


def test_sixty_seconds_of_garbage_give_nothing_and_stay_bounded():
    rng = np.random.default_rng(1234)
    garbage = rng.normal(0.0, 1000.0, 3000)          # 60 s of noise at 50 bit/s
    garbage[::97] = np.nan
    garbage[5::101] = np.inf
    garbage[7::103] = 0.0
    decoder = NavDecoder(PRN, WEEK)
    events = push_in_chunks(decoder, garbage, 0, rng.integers(1, 120, size=3000))
    assert not [e for e in events if e.parity_errors == 0], "garbage produced an accepted subframe"
    assert events == []
    assert decoder.ephemeris is None and decoder.iono is None and decoder.time_anchor is None

    # Odd deliveries: jumps back and forth in the bit count, ints, lists, empty arrays, one huge chunk.
    index = 0
    for n in rng.integers(0, 700, size=40):
        index += int(rng.integers(-500, 500))
        events = decoder.push_bits(rng.integers(-3, 4, size=n), index)
        assert not [e for e in events if e.parity_errors == 0]
        assert decoder.buffered_bits <= MAX_BUFFER_BITS
    decoder.push_bits([], 0)
    decoder.push_bits(rng.choice([-1.0, 1.0], size=300_000), 10)     # 100 minutes in one call
    assert decoder.buffered_bits <= MAX_BUFFER_BITS and decoder.ephemeris is None


def test_memory_does_not_grow_with_the_stream():
    rng = np.random.default_rng(5)
    decoder = NavDecoder(PRN, WEEK)
    values = soft(stream(K18 - 2, 130))               # 13 minutes
    garbage = rng.normal(0, 1, 9000)                  # then 3 minutes of noise
    sizes = rng.integers(1, 60, size=values.size)
    decoder.push_bits(values[:3000], 0)               # in sync by now
    tracemalloc.start()
    try:
        decoder.push_bits(values[3000:4000], 3000)
        gc.collect()
        before = tracemalloc.get_traced_memory()[0]
        at = 4000
        while at < values.size:
            decoder.push_bits(values[at:at + sizes[at]], at)
            at += sizes[at]
        for i in range(0, garbage.size, 37):
            decoder.push_bits(garbage[i:i + 37], at + i)
        gc.collect()
        after = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert after - before < 16 * 1024, f"decoder memory grew by {after - before} bytes over 16 min of bits"
    assert decoder.ephemeris == EPH


def test_garbage_after_lock_gives_no_accepted_subframe():
    bits = stream(K18 - 2, 8)[77:]
    decoder = NavDecoder(PRN, WEEK)
    good = decoder.push_bits(soft(bits), 0)
    assert len(good) == 7 and decoder.in_sync
    garbage = np.random.default_rng(3).normal(0.0, 1.0, 3000)
    events = push_in_chunks(decoder, garbage, bits.size, [25] * 200)
    assert not [e for e in events if e.parity_errors == 0]
    assert not decoder.in_sync
    assert decoder.ephemeris == EPH and decoder.time_anchor == (good[-1].start_bit_index, good[-1].t_sv_start_s)


# ------------------------------------------------------------------------------------------------- assisted mode


def test_assisted_nav_picks_the_nearest_healthy_upload():
    base = GpsTime(WEEK, 600000.0)
    uploads = [dataclasses.replace(EPH, week=WEEK, toe_s=600000.0 - 7200 * i, iode=i) for i in range(4)]
    sick = dataclasses.replace(EPH, week=WEEK, toe_s=600000.0 - 3600, iode=99, health=63)
    next_week = dataclasses.replace(EPH, week=WEEK + 1, toe_s=1200.0, iode=50)
    assist = AssistedNav(uploads + [sick, next_week, CONSTELLATION[7]])
    assert assist.ephemeris(PRN, base + -3000.0).iode == 0      # 3000 s from toe 600000, the unhealthy one nearer
    assert assist.ephemeris(PRN, base + -4000.0).iode == 1
    assert assist.ephemeris(PRN, base + 4000.0).iode == 50      # across the week boundary
    assert assist.ephemeris(PRN, base + -3600.0).iode == 0      # a tie: the later toe
    assert assist.ephemeris(PRN, GpsTime(WEEK, 600000.0 - 7200 * 3 - 4 * 3600 - 1)) is None
    assert assist.ephemeris(8, base) is None
    assert assist.ephemeris(7, START) == CONSTELLATION[7]


def test_assisted_nav_from_rinex_matches_the_file(brdc_path):
    from semperfi.iq.rinex import read_rinex_nav
    nav = read_rinex_nav(brdc_path)
    assist = AssistedNav.from_rinex(brdc_path)
    assert assist.iono == nav.iono and assist.utc == nav.utc
    t = GpsTime(2190, 518400.0 + 5000.0)
    for prn in assist.prns:
        eph = assist.ephemeris(prn, t)
        assert eph == nav.nearest(prn, t)
        if eph is not None:
            assert eph.health == 0 and abs(GpsTime(eph.week, eph.toe_s).seconds - t.seconds) <= 4 * 3600
    sick = [e for e in nav.ephemerides if e.health != 0]
    for e in sick:
        got = assist.ephemeris(e.prn, GpsTime(e.week, e.toe_s))
        assert got is None or got.health == 0
    assert all(assist.ephemeris(prn, t + 86400.0 * 3) is None for prn in assist.prns)

    # The decoder and the assistance agree on what the satellite broadcasts.
    eph = assist.ephemeris(12, t)
    k = int(eph.toe_s) // 6 - 1
    decoder = NavDecoder(12, full_week_hint=eph.week)
    decoder.push_bits(soft(stream(k, 12, eph=eph, iono=nav.iono, utc=nav.utc)[200:]), 0)
    assert decoder.ephemeris == lnav.quantize_ephemeris(eph)

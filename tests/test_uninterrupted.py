"""Claims of a receiver that never stops answering: the GPS week from any subframe 1, a replacing channel that need
not read a whole frame again, and a bug that is one line, an event and exit 70 with every output kept."""

import json

import click
import numpy as np
import pytest
from click.testing import CliRunner

from semperfi.cli import _OneLineGroup
from semperfi.defense.config import load_config
from semperfi.errors import InternalError
from semperfi.gps import lnav
from semperfi.receiver.chain import Receiver
from semperfi.receiver.navigation import NavDecoder
from semperfi.receiver.run import run_file
from semperfi.sim.run import simulate_to_file
from semperfi.sim.scenario import load_scenario

from test_navigation import CONSTELLATION, EPH, IONO, PRN, START, UTC, WEEK, soft


def frame_bits(k_first: int, n: int) -> np.ndarray:
    return np.concatenate([lnav.subframe_bits(k, EPH, IONO, UTC, CONSTELLATION) for k in range(k_first, k_first + n)])


K1 = (int(START.tow_s) // 6 // 5 + 1) * 5     # a subframe 1 (the first of a frame) after START


def test_the_week_is_read_from_any_subframe_1_with_good_parity():
    bits = frame_bits(K1, 1)
    sf = lnav.decode_subframe(bits)
    assert lnav.week_of_subframe1(sf) == WEEK
    assert lnav.week_of_subframe1(sf, full_week_hint=WEEK + 1000) == WEEK + 1024, "the 10-bit week nearest the hint"
    with pytest.raises(ValueError):
        lnav.week_of_subframe1(lnav.decode_subframe(frame_bits(K1 + 1, 1)))
    decoder = NavDecoder(PRN)
    decoder.push_bits(soft(frame_bits(K1, 2)), 0)
    assert decoder.week == WEEK and decoder.ephemeris is None, "the week long before a whole ephemeris"


def test_a_decoder_that_replaces_another_completes_the_ephemeris_with_what_it_lacks():
    """The first channel read subframes 2 and 3 before it went (a verdict, a loss of lock); the one that replaces it
    reads subframe 1 of the next frame and has the ephemeris 6 s later, not a whole frame (30 s) later."""
    first = NavDecoder(PRN)
    first.push_bits(soft(frame_bits(K1 + 1, 3)), 0)          # subframes 2, 3, 4
    assert first.ephemeris is None
    alone, adopting = NavDecoder(PRN), NavDecoder(PRN)
    adopting.adopt(first)
    for d in (alone, adopting):
        d.push_bits(soft(frame_bits(K1 + 5, 2), seed=4), 0)  # subframe 1 and 2 of the next frame
    assert alone.ephemeris is None
    assert adopting.ephemeris is not None and adopting.ephemeris.toe_s == EPH.toe_s and adopting.ephemeris.prn == PRN
    # its time anchor is its own channel's: the latest subframe it read, at its own bit index
    assert adopting.time_anchor == (300, float(6 * (K1 + 6))), adopting.time_anchor


@pytest.fixture(scope="module")
def short_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "s.bin"
    cfg = load_scenario(None, ["signal.fs_hz=2e6", "time.duration_s=3", 'signal.format="ishort"'])
    simulate_to_file(cfg, path)
    return path


class FailingReceiver(Receiver):
    """A receiver with a bug that shows at its fifth chunk."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.fed = 0

    def feed(self, chunk):
        self.fed += 1
        if self.fed == 5:
            raise ZeroDivisionError("a bug")
        super().feed(chunk)


def test_an_internal_error_is_an_event_and_one_line_with_the_outputs_kept(short_scene, tmp_path):
    summary = run_file(short_scene, None, None, None, load_config(None, []), tmp_path / "out",
                       receiver_factory=FailingReceiver)
    assert summary.internal_error and "ZeroDivisionError: a bug" in summary.internal_error
    assert "\n" not in summary.internal_error
    events = [json.loads(line) for line in open(tmp_path / "out" / "events.jsonl")]
    failed = [e for e in events if e["event"] == "internal_error"]
    assert len(failed) == 1 and failed[0]["where"].startswith("test_uninterrupted.py:"), failed
    assert failed[0]["t_rx_s"] > 0
    assert events[0]["event"] == "input", "what came before is kept"
    for name in ("fixes.csv", "fixes.nmea", "fixes.gpx", "fixes.geojson", "config.toml"):
        assert (tmp_path / "out" / name).is_file(), name
    json.load(open(tmp_path / "out" / "fixes.geojson"))   # closed as a whole document


def test_whatever_escapes_a_command_is_one_line_and_its_exit_code():
    @click.group(cls=_OneLineGroup)
    def cli():
        pass

    @cli.command()
    def boom():
        raise KeyError("deep inside")

    @cli.command()
    def refuse():
        raise InternalError("said plainly")

    result = CliRunner().invoke(cli, ["boom"])
    assert result.exit_code == InternalError.exit_code == 70
    lines = result.output.strip().splitlines()
    assert (len(lines) == 1 and lines[0].startswith("semperfi: internal error: KeyError")
            and "Traceback" not in result.output)
    result = CliRunner().invoke(cli, ["refuse"])
    assert result.exit_code == 70 and result.output.strip() == "semperfi: error: said plainly"

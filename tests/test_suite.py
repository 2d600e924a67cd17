"""`semperfi eval --suite` (issue 26): the paper's evaluation in CI-sized form end to end (a real attack recovered,
every figure linked by the report), a case rendered by our simulator as it is by GPS-SDR-SIM, and the one-line
errors."""

import csv
import json
import math
import re
import subprocess
import sys

import pytest

from semperfi.eval.ours import scenario_sets
from semperfi.eval.paper import PLANS, PLACE
from semperfi.eval.suite import FIGURES_JSON, RUN_KEYS, RUNS_CSV, render_suite_report, run_suite
from semperfi.eval.xgen import OURS, Case
from semperfi.flight.maneuver import ManeuverLimits
from semperfi.sim.attacker import AttackPlan
from semperfi.sim.scenario import load_scenario


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, brdc_path):
    out = tmp_path_factory.mktemp("suite")
    report = run_suite("tiny", out, str(brdc_path), OURS)
    return out, report


def test_the_tiny_suite_recovers_the_truth_and_its_report_links_every_figure(tiny):
    out, report = tiny
    figures = json.loads((out / FIGURES_JSON).read_text())["figures"]
    assert [f["key"] for f in figures] == list(PLANS["tiny"].figures)
    assert all(f["error"] is None for f in figures), [f["error"] for f in figures]
    page = report.read_text()
    for f in figures:
        assert f["title"] in page
        if f["png"]:
            assert (out / f["png"]).stat().st_size > 10_000          # a drawn figure, not an empty canvas
            assert f"<img src='{f['png']}'" in page
    with open(out / RUNS_CSV, newline="") as fh:
        reader = csv.DictReader(fh)
        runs = list(reader)
    assert tuple(reader.fieldnames) == RUN_KEYS
    # the static attack (1 km, +6 dB, synchronized), fixed
    # within 10 m of the truth over its last 10 s and on most epochs from the clean first fix
    attacked = [r for r in runs if "1000m" in r["label"]]
    assert len(runs) == 1 and len(attacked) == 1     # the clean scene is run to its first fix only
    assert float(attacked[0]["last_mean_m"]) < 10.0 and float(attacked[0]["availability"]) > 0.9
    assert all(r["good_beyond_hpl"] == "0" and r["crash"] == "False" for r in runs)


def test_the_suite_figures_say_ours_beside_the_papers(tiny):
    out, _ = tiny
    figures = {f["key"]: f for f in json.loads((out / FIGURES_JSON).read_text())["figures"]}
    rows = {what: (paper, ours) for what, paper, ours in figures["maneuvers"]["rows"]}
    low, high = (float(v) for v in re.findall(r"[\d.]+", rows["flight time"][1]))
    assert rows["flight time"][0] == "10-20 s" and 0 < low <= high <= ManeuverLimits().max_duration_s
    low, _ = (float(v) for v in re.findall(r"[\d.]+", rows["distance from the trigger at the end"][1]))
    assert low >= ManeuverLimits().min_end_distance_m
    static = figures["static"]["rows"]
    separation = float(re.search(r"\(([\d.]+) ns", static[0][2]).group(1))
    # a 1 km horizontal offset moves each range by 1 km x cos(elevation) x cos(azimuth difference): on average
    # between a tenth and two thirds of it
    assert 0.1 * 1000 / 0.2998 < separation < 0.67 * 1000 / 0.2998
    timing = figures["timing"]["rows"][0]
    assert "Xeon 2.12 s" in timing[1] and float(timing[2].split(" s")[0]) > 0


def test_the_report_renders_again_from_its_figures_alone(tiny):
    out, report = tiny
    before = report.read_text()
    report.unlink()
    assert render_suite_report(out / FIGURES_JSON).read_text() == before


@pytest.mark.parametrize("kind", ["static", "takeover", "push"])
def test_a_case_is_the_same_attack_on_our_simulator(kind, tmp_path):
    case = Case(PLACE, 1000.0, 6.0, date="2022/01/01,00:04:07", azimuth_deg=30.0, duration_s=20.0, fs_hz=2.0e6,
                generator=OURS, path_loss=True, cn0_dbhz=47.0)
    if kind == "takeover":
        case = Case(PLACE, 0.0, 3.0, duration_s=20.0, spoof_motion="x.csv", takeover_hold_s=5.0, takeover_m_s=8.0,
                    generator=OURS)
    if kind == "push":
        case = Case(PLACE, 0.0, 10.0, duration_s=20.0, push_ns_per_s=25.0, push_from_s=8.0, generator=OURS)
    cfg = load_scenario(None, scenario_sets(case, None))
    plan = AttackPlan.from_config(cfg["attacker"])
    assert cfg["receiver"]["lat_deg"] == PLACE.lat_deg and cfg["signal"]["fs_hz"] == case.fs_hz
    assert cfg["constellation"]["troposphere"] is False and cfg["receiver"]["clock_bias_s"] == 0.0
    assert plan.power_advantage_db == case.advantage_db and plan.advantage_db(0.0) == case.advantage_db
    if kind == "static":
        assert cfg["time"]["start"] == "2022-01-01T00:04:07" and cfg["constellation"]["cn0_model"] == "elevation"
        assert plan.offset_enu_m[0] == pytest.approx(1000 * math.sin(math.radians(30)))
        assert plan.offset_enu_m[1] == pytest.approx(1000 * math.cos(math.radians(30)))
    if kind == "takeover":
        assert plan.drag_m(5.0) == 0.0 and plan.drag_m(7.0) == pytest.approx(16.0)
    if kind == "push":
        assert plan.delay_s(8.0) == 0.0 and plan.delay_s(10.0) == pytest.approx(50e-9)


def test_eval_wants_a_suite_or_a_sweep_and_report_refuses_what_is_not_a_suite(tmp_path):
    def cli(*args):
        return subprocess.run([sys.executable, "-m", "semperfi.cli", *args], capture_output=True, text=True,
                              timeout=120)
    for args in (["eval"], ["eval", "--suite", "tiny", "--sweep", "x.toml"], ["eval", "--suite", "nope"]):
        r = cli(*args)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    bad = tmp_path / "figures.json"
    bad.write_text('{"suite": "x", "figures": [1]}')
    r = cli("report", str(bad))
    assert r.returncode != 0 and "not a suite's figures.json" in r.stderr and "Traceback" not in r.stderr

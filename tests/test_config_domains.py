"""Every configuration key with a domain (receiver, defence, scenario) rejects a value outside it with one line that
names the key, its domain and the value; the defaults lie inside; each section's dataclass is the one source."""
import subprocess
import sys
from dataclasses import fields

import pytest

from semperfi import config
from semperfi.defense.config import SECTIONS as DEFENSE, load_config
from semperfi.receiver.config import SECTIONS as RECEIVER
from semperfi.sim.scenario import SECTIONS as SCENARIO, load_scenario

RUN = {**RECEIVER, **DEFENSE}


def _keys(sections):
    return [(f"{name}.{f.name}", f) for name, cls in sections.items() for f in fields(cls)
            if config.domain_text(f) is not None]


def _outside(f) -> str:
    """A TOML literal just outside the key's domain."""
    m = f.metadata
    if m["choices"]:
        value = '"nonsense"'
    else:
        high = m["high"]
        value = str(high + 1) if isinstance(high, int) else repr(float(high) * 2 + 1)
    return f"[{value}]" if m["each"] else value


def test_defaults_lie_inside_their_domains():
    config.check(config.defaults(RUN), RUN)
    config.check(config.defaults(SCENARIO), SCENARIO)


@pytest.mark.parametrize("name, f", _keys(RUN), ids=[k for k, _ in _keys(RUN)])
def test_a_run_key_outside_its_domain_is_refused_naming_it(name, f):
    with pytest.raises(ValueError) as err:
        load_config(None, [f"{name}={_outside(f)}"])
    assert f"'{name}' must be {config.domain_text(f)}" in str(err.value)


@pytest.mark.parametrize("name, f", _keys(SCENARIO), ids=[k for k, _ in _keys(SCENARIO)])
def test_a_scenario_key_outside_its_domain_is_refused_naming_it(name, f):
    with pytest.raises(ValueError) as err:
        load_scenario(None, [f"{name}={_outside(f)}"])
    assert f"'{name}' must be {config.domain_text(f)}" in str(err.value)


def test_a_count_or_a_prn_must_be_whole():
    for bad in ("acquisition.prns=[1.5]", "attacker.prns=[3.0]"):
        with pytest.raises(ValueError, match="between 1 and 32"):
            (load_scenario if bad.startswith("attacker") else load_config)(None, [bad])


def test_an_unknown_key_and_malformed_toml_are_one_line(tmp_path):
    with pytest.raises(ValueError, match="unknown configuration key 'pvt.nosuch'"):
        load_config(None, ["pvt.nosuch=1"])
    bad = tmp_path / "bad.toml"
    bad.write_text("[pvt\nrate_hz = ")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_config(bad, [])


def test_a_section_is_read_as_its_dataclass():
    from semperfi.receiver.config import Integrity
    cfg = load_config(None, ["integrity.pfa=1e-6"])
    assert config.section(cfg, "integrity", Integrity).pfa == 1e-6


@pytest.mark.parametrize("key", ["acquisition.pfa", "tracking.channels", "defense.mode", "output.formats"])
def test_cli_refuses_out_of_range_config_in_one_line(key, tmp_path):
    dummy = tmp_path / "x.bin"
    dummy.write_bytes(b"\0" * 4096)
    f = dict(_keys(RUN))[key]
    res = subprocess.run([sys.executable, "-m", "semperfi.cli", "run", str(dummy), "--fs", "2e6", "--format", "ibyte",
                          "--out", str(tmp_path / "out"), "--set", f"{key}={_outside(f)}"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode != 0, f"exit 0 for {key} out of range"
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0] and config.domain_text(f) in lines[0], res.stderr

"""Every receiver/defence configuration key with a domain rejects a value outside it: one line, non-zero exit."""
import subprocess
import sys

import pytest

from semperfi import config
from semperfi.defense.config import DEFAULTS as DEFENSE, DOMAINS as DEFENSE_DOMAINS
from semperfi.receiver.config import DEFAULTS as RECEIVER, DOMAINS as RECEIVER_DOMAINS

DOMAINS = {**RECEIVER_DOMAINS, **DEFENSE_DOMAINS}
DEFAULTS = {**RECEIVER, **DEFENSE}


def _outside(domain):
    """A TOML literal just outside the domain."""
    kind = domain[0]
    if kind == "one":
        return '"nonsense"'
    if kind == "each":
        rule = domain[1:]
        if len(rule) == 2 and all(isinstance(r, (int, float)) for r in rule):
            return f"[{rule[1] + 1}]"
        return '["nonsense"]'
    low, high = domain
    return repr(float(high) * 2 + 1) if isinstance(high, float) else str(high + 1)


def test_defaults_lie_inside_their_domains():
    config.check_domains(DEFAULTS, DOMAINS)


@pytest.mark.parametrize("key", sorted(DOMAINS))
def test_value_outside_domain_is_refused(key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        config.check_domains(config.load(DEFAULTS, None, [f"{key}={_outside(DOMAINS[key])}"]), DOMAINS)


@pytest.mark.parametrize("key", ["acquisition.pfa", "tracking.channels", "defense.mode", "output.formats"])
def test_cli_refuses_out_of_range_config_in_one_line(key, tmp_path):
    dummy = tmp_path / "x.bin"
    dummy.write_bytes(b"\0" * 4096)
    res = subprocess.run([sys.executable, "-m", "semperfi.cli", "run", str(dummy), "--fs", "2e6", "--format", "ibyte",
                          "--out", str(tmp_path / "out"), "--set", f"{key}={_outside(DOMAINS[key])}"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode != 0, f"exit 0 for {key} out of range"
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0], f"stderr is not one line naming {key}: {res.stderr!r}"

"""Run configuration: one TOML file with every key defaulted, overridden by `--set section.key=value`."""

import copy
import json
import tomllib
from pathlib import Path
from typing import Any

MAX_CONFIG_BYTES = 1 << 20


def _parse_value(text: str) -> Any:
    """A --set value as TOML would read it; a bare word is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def merge(defaults: dict, overrides: dict, where: str = "") -> dict:
    """defaults updated by overrides; an unknown key or a value of the wrong type is a ValueError."""
    out = copy.deepcopy(defaults)
    for key, value in overrides.items():
        name = f"{where}{key}"
        if key not in defaults:
            raise ValueError(f"unknown configuration key '{name}' (known: {', '.join(sorted(defaults))})")
        ref = defaults[key]
        if isinstance(ref, dict):
            if not isinstance(value, dict):
                raise ValueError(f"configuration key '{name}' is a section, not a value")
            out[key] = merge(ref, value, f"{name}.")
            continue
        if isinstance(ref, bool) != isinstance(value, bool):
            raise ValueError(f"configuration key '{name}' wants true or false, got {value!r}")
        if isinstance(ref, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if ref is not None and not isinstance(value, type(ref)):
            raise ValueError(f"configuration key '{name}' wants a {type(ref).__name__}, got {value!r}")
        out[key] = value
    return out


def load(defaults: dict, path: str | Path | None = None, sets: list[str] = ()) -> dict:
    """The effective configuration: defaults <- TOML file <- --set overrides."""
    cfg = copy.deepcopy(defaults)
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"configuration file not found: {path}")
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise ValueError(f"{path}: too large for a configuration file")
        try:
            cfg = merge(cfg, tomllib.loads(path.read_text()))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: not valid TOML ({exc})") from None
    for item in sets:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set wants section.key=value, got '{item}'")
        nested: dict = {}
        node = nested
        parts = key.strip().split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = _parse_value(text.strip())
        cfg = merge(cfg, nested)
    return cfg


def dumps_toml(cfg: dict) -> str:
    """The configuration as TOML, to be written beside every output."""
    lines: list[str] = []

    def emit(section: dict, prefix: str) -> None:
        scalars = {k: v for k, v in section.items() if not isinstance(v, dict)}
        if prefix and scalars:
            lines.append(f"[{prefix}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {json.dumps(v)}")
        if scalars:
            lines.append("")
        for k, v in section.items():
            if isinstance(v, dict):
                emit(v, f"{prefix}.{k}" if prefix else k)

    emit(cfg, "")
    return "\n".join(lines)


def check_domains(cfg: dict, domains: dict) -> None:
    """A ValueError naming the first key whose value lies outside its domain.

    A domain is (low, high) inclusive; ("one", *choices) for a string; ("each", low, high) or ("each", *choices)
    for a list, applied to every element."""
    for name, domain in domains.items():
        node: Any = cfg
        for part in name.split("."):
            node = node[part]
        values, rule = ([node], domain)
        if domain[0] in ("one", "each"):
            values = list(node) if domain[0] == "each" else [node]
            rule = domain[1:]
        for value in values:
            numeric = (domain[0] != "one" and len(rule) == 2
                       and all(isinstance(r, (int, float)) and not isinstance(r, bool) for r in rule))
            if numeric:
                ok = isinstance(value, (int, float)) and not isinstance(value, bool) and rule[0] <= value <= rule[1]
                want = f"between {rule[0]:g} and {rule[1]:g}"
            else:
                ok = value in rule
                want = "one of " + ", ".join(map(str, rule))
            if not ok:
                raise ValueError(f"configuration key '{name}' must be {want}, got {value!r}")

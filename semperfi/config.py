"""Run configuration: one TOML file with every key defaulted, overridden by `--set section.key=value`.

Each section is a frozen dataclass whose fields are its keys (`key`: the default, the unit, the domain and what it
means): the one source of the defaults (`defaults`), of the checks (`check`: one line naming the key, its domain and
the value) and of the typed view the code reads (`section`).
"""

import copy
import json
import tomllib
from dataclasses import MISSING, field, fields
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


def dumps_toml(cfg: dict, sections: dict[str, type] | None = None) -> str:
    """The configuration as TOML, to be written beside every output; with its sections' dataclasses, each key
    followed by what it accepts and means."""
    lines: list[str] = []
    described = {(name, f.name): f for name, cls in (sections or {}).items() for f in fields(cls)}

    def emit(section: dict, prefix: str) -> None:
        scalars = {k: v for k, v in section.items() if not isinstance(v, dict)}
        if prefix and scalars:
            lines.append(f"[{prefix}]")
        for k, v in scalars.items():
            f = described.get((prefix, k))
            words = [] if f is None else [w for w in (domain_text(f), f.metadata["doc"]) if w]
            lines.append(f"{k} = {json.dumps(v)}" + (f"    # {'; '.join(words)}" if words else ""))
        if scalars:
            lines.append("")
        for k, v in section.items():
            if isinstance(v, dict):
                emit(v, f"{prefix}.{k}" if prefix else k)

    emit(cfg, "")
    return "\n".join(lines)


def key(default: Any, low: float | None = None, high: float | None = None, *, choices: tuple = (),
        each: bool = False, unit: str = "", doc: str = ""):
    """A configuration key as a dataclass field: its default, and its domain -- low..high inclusive, or choices;
    each: the rule holds for every element of a list -- its unit and what it means."""
    meta = {"low": low, "high": high, "choices": tuple(choices), "each": each, "unit": unit, "doc": doc}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


def defaults(sections: dict[str, type]) -> dict:
    """{section: {key: default}} of sections' dataclasses, the form TOML and --set override."""
    return {name: {f.name: f.default_factory() if f.default is MISSING else f.default for f in fields(cls)}
            for name, cls in sections.items()}


def domain_text(f) -> str | None:
    """What a key accepts, in words (None: any value of its type)."""
    m = f.metadata
    if m.get("choices"):
        text = "one of " + ", ".join(map(str, m["choices"]))
    elif m.get("low") is not None:
        text = f"between {m['low']:g} and {m['high']:g}" + (f" {m['unit']}" if m["unit"] else "")
    else:
        return None
    return ("each " if m["each"] else "") + text


def _inside(value: Any, m) -> bool:
    if m["choices"]:
        return value in m["choices"]
    whole = isinstance(m["low"], int) and isinstance(m["high"], int)     # whole bounds: a count, a PRN
    return (isinstance(value, int if whole else (int, float)) and not isinstance(value, bool)
            and m["low"] <= value <= m["high"])


def check(cfg: dict, sections: dict[str, type]) -> None:
    """A ValueError naming the first key of sections whose value lies outside its domain, the domain and the value."""
    for name, cls in sections.items():
        for f in fields(cls):
            want = domain_text(f)
            value = cfg[name][f.name]
            if want is not None and not all(_inside(v, f.metadata) for v in (value if f.metadata["each"] else
                                                                             [value])):
                raise ValueError(f"configuration key '{name}.{f.name}' must be {want}, got {value!r}")


def section(cfg: dict, name: str, cls: type):
    """A checked configuration's section as its frozen dataclass (lists as tuples)."""
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in cfg[name].items()})

"""The rooms of the package import only what docs/architecture.md lets them: the receiver and the defence never
see the simulator or the evaluation (the truth), the flight side talks to the receiver only over the link."""

import ast
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "semperfi"
LEAVES = {"address", "config", "errors", "face", "progress"}     # top-level modules with no room imports of their own
MAY_IMPORT = {
    "gps": set(),
    "iq": {"gps"},
    "receiver": {"gps", "iq"},
    "defense": {"gps", "iq", "receiver"},
    "flight": {"gps"},
    "sim": {"gps", "iq", "flight"},
}


def _imported_rooms(path: Path) -> set[str]:
    """The package's top-level names a module imports (relative or absolute)."""
    rooms = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level >= 2 and node.module:
                rooms.add(node.module.split(".")[0])
            elif node.level >= 2:
                rooms.update(a.name for a in node.names)
            elif node.level == 0 and node.module and node.module.startswith("semperfi."):
                rooms.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            rooms.update(a.name.split(".")[1] for a in node.names if a.name.startswith("semperfi."))
    return rooms


def test_each_room_imports_only_what_it_may():
    broken = []
    for room, allowed in MAY_IMPORT.items():
        for path in sorted((PACKAGE / room).glob("*.py")):
            extra = _imported_rooms(path) - allowed - LEAVES - {"__version__"} - {room}
            if extra:
                broken.append(f"{room}/{path.name} imports {sorted(extra)}")
    assert not broken, "; ".join(broken)


def _cross_room_imports():
    """(importing file, room, module within the room or None for its face, names) for every import of a room's names
    from outside it, in the package."""
    rooms = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        here = rel.parts[0] if len(rel.parts) > 1 else None
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                parts = [a.name.split(".") for a in node.names if a.name.startswith("semperfi.")]
                yield from ((rel, p[1], ".".join(p[2:]) or None, ()) for p in parts if p[1] != here)
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = ["semperfi", *rel.parts[:-1]][:len(rel.parts) - node.level + 1]
                parts = base + (node.module.split(".") if node.module else [])
            else:
                parts = (node.module or "").split(".")
            if len(parts) >= 2 and parts[0] == "semperfi" and parts[1] in rooms and parts[1] != here:
                yield rel, parts[1], ".".join(parts[2:]) or None, tuple(a.name for a in node.names)


def test_the_rooms_meet_only_through_their_faces():
    """A room uses another room's names through that room's __init__ (semperfi.face: loaded when first used), and a
    face holds exactly the names other rooms use: nothing reaches past it, nothing on it is unused."""
    import importlib
    past = [f"{rel} imports semperfi.{room}.{module}" for rel, room, module, _ in _cross_room_imports() if module]
    assert not past, "; ".join(past)
    used: dict[str, set[str]] = {}
    for _, room, _, names in _cross_room_imports():
        used.setdefault(room, set()).update(names)
    for room in MAY_IMPORT.keys() | {"eval"}:
        face = importlib.import_module(f"semperfi.{room}")
        assert set(face.__all__) == used.get(room, set()), (room, set(face.__all__) ^ used.get(room, set()))
        for name in face.__all__:
            assert getattr(face, name) is not None, (room, name)


def test_the_leaf_modules_import_no_room():
    for name in LEAVES:
        rooms = _imported_rooms(PACKAGE / f"{name}.py")
        assert not rooms, f"{name}.py imports {sorted(rooms)}"


def test_the_check_sees_a_forbidden_import(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("from ..sim.world import World\nfrom ..gps import codes\nimport semperfi.eval.metrics\n")
    assert _imported_rooms(module) == {"sim", "gps", "eval"}


def test_the_code_is_ruff_clean():
    """ruff, as configured in pyproject.toml, on the package, the tests, the benchmarks and the Python scripts."""
    scripts = [p for p in sorted((REPO / "scripts").iterdir())
               if p.is_file() and p.read_text(encoding="utf-8", errors="replace").startswith("#!/usr/bin/env python")]
    run = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "semperfi", "tests", "benchmarks",
                          *map(str, scripts)], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-1000:]


def test_every_exception_a_user_can_meet_is_a_semperfi_error():
    """One base for what is told to the user (errors.SemperFiError: the command line maps it to one line and its exit
    code in one place); only private flow-control exceptions of a module stand outside it."""
    import importlib
    import inspect
    import pkgutil

    import semperfi
    from semperfi.errors import SemperFiError
    internal = {"semperfi.iq.rtltcp.StreamEnded"}   # rtltcp -> source: turned into a SourceError there
    found, outside = 0, []
    for info in pkgutil.walk_packages(semperfi.__path__, "semperfi."):
        module = importlib.import_module(info.name)
        for name, cls in inspect.getmembers(module, inspect.isclass):
            if cls.__module__ != info.name or not issubclass(cls, BaseException):
                continue
            found += 1
            where = f"{info.name}.{name}"
            if not issubclass(cls, SemperFiError) and not name.startswith("_") and where not in internal:
                outside.append(where)
    assert found >= 10 and not outside, outside

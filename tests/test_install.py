"""Every package SemperFi imports is one it declares: a module-level import among the runtime dependencies of
pyproject.toml, one inside a function (an optional feature) among them or an extra's.

Catches an undeclared runtime dependency (issue 12: `rich` was imported but not declared) by reading the imports
of every module, which is what installing into a clean environment and importing every module there found, without
the minute and a half that took. The install itself is what the README's commands (and CI) run."""
import ast
import functools
import re
import sys
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _declared() -> tuple[set[str], set[str]]:
    """(runtime distributions, the extras' distributions), canonical names."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    name = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)")
    runtime = {_canonical(name.match(d).group(1)) for d in project["dependencies"]}
    extras = {_canonical(name.match(d).group(1)) for ds in project.get("optional-dependencies", {}).values()
              for d in ds}
    return runtime, extras


def _imports(source: str) -> tuple[set[str], set[str]]:
    """(top-level names imported at module level, those imported inside functions) of absolute imports."""
    module, inner = set(), set()

    def visit(node, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            names = []
            if isinstance(child, ast.Import):
                names = [a.name.split(".")[0] for a in child.names]
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                names = [child.module.split(".")[0]]
            (inner if in_function else module).update(names)
            visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(ast.parse(source), False)
    return module, inner


_provides = functools.cache(packages_distributions)   # import name -> distributions: it reads every one installed


def _undeclared(source: str, runtime: set[str], extras: set[str]) -> set[str]:
    """Imports of a module's source that no declared distribution provides."""
    provides = _provides()
    module, inner = _imports(source)

    def dists(name: str) -> set[str]:
        return {_canonical(d) for d in provides.get(name, [name])}

    third = lambda names: {n for n in names if n not in sys.stdlib_module_names and n != "semperfi"}  # noqa: E731
    return ({n for n in third(module) if not dists(n) & runtime}
            | {n for n in third(inner) if not dists(n) & (runtime | extras)})


def test_every_package_a_module_imports_is_declared():
    runtime, extras = _declared()
    modules = sorted((ROOT / "semperfi").rglob("*.py"))
    assert len(modules) > 30, modules
    missing = {str(m.relative_to(ROOT)): names for m in modules
               if (names := _undeclared(m.read_text(), runtime, extras))}
    assert not missing, f"imported but not declared in pyproject.toml: {missing}"


def test_the_check_sees_an_undeclared_import_and_an_extra_used_at_module_level():
    runtime, extras = _declared()
    assert _undeclared("import numpy\nfrom rich.console import Console\n", runtime, extras) == set()
    assert _undeclared("import requests\n", runtime, extras) == {"requests"}
    assert _undeclared("import pyarrow\n", runtime, extras) == {"pyarrow"}            # an extra, needed at import
    assert _undeclared("def f():\n    import pyarrow\n", runtime, extras) == set()    # an extra, where it is used
    assert _undeclared("import json, os.path\n", runtime, extras) == set()

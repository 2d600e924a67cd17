"""The package installs into a clean virtual environment and every module of it imports there.

Catches an undeclared runtime dependency (issue 12: `rich` was imported but not declared)."""
import subprocess
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

IMPORT_ALL = """
import importlib, pkgutil, semperfi
names = [m.name for m in pkgutil.walk_packages(semperfi.__path__, 'semperfi.')]
for name in names:
    importlib.import_module(name)
print(len(names))
"""


@pytest.mark.slow
def test_clean_venv_imports_every_module(tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    python = env_dir / "bin" / "python"
    pip = subprocess.run([str(python), "-m", "pip", "install", "-q", str(ROOT)],
                         capture_output=True, text=True, timeout=600)
    assert pip.returncode == 0, f"pip install failed:\n{pip.stderr[-2000:]}"
    # Run outside the source tree so the installed copy, not the worktree, is imported.
    imported = subprocess.run([str(python), "-c", IMPORT_ALL], capture_output=True, text=True,
                              cwd=tmp_path, timeout=300)
    assert imported.returncode == 0, f"a module failed to import in a clean venv:\n{imported.stderr[-2000:]}"
    assert int(imported.stdout.split()[-1]) > 30, f"too few modules found: {imported.stdout!r}"

"""What the ArduCopter SITL tests share: where SITL is, and scripts/sitl-fly (its Sitl process, its Observer) as a
module."""

import importlib.machinery
import importlib.util
from pathlib import Path

SITL_DIR = Path(__file__).parents[1].parent / "shared" / "sitl"


def sitl_fly():
    """scripts/sitl-fly, imported (it has no .py suffix)."""
    path = Path(__file__).parents[1] / "scripts" / "sitl-fly"
    loader = importlib.machinery.SourceFileLoader("sitl_fly", str(path))
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader("sitl_fly", loader))
    loader.exec_module(module)
    return module

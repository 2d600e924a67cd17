"""Where the ArduCopter SITL the tests fly against is (../shared/sitl)."""

from pathlib import Path

SITL_DIR = Path(__file__).parents[1].parent / "shared" / "sitl"
SITL_BINARY = SITL_DIR / "arducopter"


def sitl_fly():
    """scripts/sitl-fly, imported (it has no .py suffix)."""
    import importlib.machinery
    import importlib.util
    path = Path(__file__).parents[1] / "scripts" / "sitl-fly"
    loader = importlib.machinery.SourceFileLoader("sitl_fly", str(path))
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader("sitl_fly", loader))
    loader.exec_module(module)
    return module

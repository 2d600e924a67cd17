"""Where the ArduCopter SITL the tests fly against is (../shared/sitl)."""

from pathlib import Path

from script_modules import load_script

SITL_DIR = Path(__file__).parents[1].parent / "shared" / "sitl"
SITL_BINARY = SITL_DIR / "arducopter"


def sitl_fly():
    """scripts/sitl-fly, imported."""
    return load_script("sitl-fly")

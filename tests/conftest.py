import os
import shutil
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SHARED_DATA = SHARED / "data"
BRDC = SHARED_DATA / "brdc0010.22n"
# the tools built for this machine (gps-sdr-sim): the cross-generator tests run in CI too, not only where a
# developer put them on PATH
if shutil.which("gps-sdr-sim") is None and (SHARED / "bin" / "gps-sdr-sim").is_file():
    os.environ["PATH"] = f"{SHARED / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"


@pytest.fixture(scope="session")
def brdc_path() -> Path:
    if not BRDC.is_file():
        pytest.skip(f"{BRDC} not present (the shared data folder sits beside the repository)")
    return BRDC

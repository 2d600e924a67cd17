from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BRDC = SHARED_DATA / "brdc0010.22n"


@pytest.fixture(scope="session")
def brdc_path() -> Path:
    if not BRDC.is_file():
        pytest.skip(f"{BRDC} not present (the shared data folder sits beside the repository)")
    return BRDC

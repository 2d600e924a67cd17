import os
from pathlib import Path

import pytest

# pytest-xdist's workers share the machine's cores: each gets its share of threads instead of all of them (two
# workers of two threads each on two cores ran the defended receiver 18 % slower, from the switching, results equal)
_WORKERS = os.environ.get("PYTEST_XDIST_WORKER_COUNT", "")
if _WORKERS.isdigit() and "SEMPERFI_THREADS" not in os.environ:
    os.environ["SEMPERFI_THREADS"] = str(max(1, len(os.sched_getaffinity(0)) // int(_WORKERS)))

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BRDC = SHARED_DATA / "brdc0010.22n"


@pytest.fixture(scope="session")
def brdc_path() -> Path:
    if not BRDC.is_file():
        pytest.skip(f"{BRDC} not present (the shared data folder sits beside the repository)")
    return BRDC

import os
import shutil
import tempfile
from pathlib import Path

import pytest

from semperfi.receiver.workers import THREADS_ENV

# Each xdist worker takes one core's threads: two signal-level files run side by side for most of the suite, and two
# defended runs on two cores took 27.3 s with one thread each against 33.2 s with two (the threaded path keeps a
# test of its own, tests/test_tracking.py). Set by the user, it is theirs.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault(THREADS_ENV, "1")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BRDC = SHARED_DATA / "brdc0010.22n"


@pytest.fixture(scope="session")
def brdc_path() -> Path:
    if not BRDC.is_file():
        pytest.skip(f"{BRDC} not present (the shared data folder sits beside the repository)")
    return BRDC


def pytest_configure(config):
    """GPS-SDR-SIM's scenes rendered once for the whole run, both workers (they inherit this process's environment):
    a longer scene serves a shorter case, and most cross-generator tests share Boston's static scene and its
    spoofer's. Removed at the end (a run renders gigabytes). Set by the user, the folder is theirs."""
    from semperfi.eval.xgen import SCENES_ENV
    if os.environ.get("PYTEST_XDIST_WORKER") or os.environ.get(SCENES_ENV):
        return
    os.environ[SCENES_ENV] = config._semperfi_scenes = tempfile.mkdtemp(prefix="semperfi-scenes-")


def pytest_unconfigure(config):
    if getattr(config, "_semperfi_scenes", None):
        shutil.rmtree(config._semperfi_scenes, ignore_errors=True)

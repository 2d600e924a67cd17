from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BRDC = SHARED_DATA / "brdc0010.22n"


@pytest.fixture(scope="session")
def brdc_path() -> Path:
    if not BRDC.is_file():
        pytest.skip(f"{BRDC} not present (the shared data folder sits beside the repository)")
    return BRDC


# The longest files first (worker seconds, measured), so that pytest-xdist (--dist loadfile hands out files in the
# order collected) starts them at once and ends on short ones: in alphabetical order the cross-generator files came
# last, one worker ran them alone for minutes while the other idled.
LONGEST_FIRST = ("test_xgen.py", "test_gnss_sdr.py", "test_xgen_availability.py", "test_sitl.py", "test_defense.py",
                 "test_closed_loop.py", "test_install.py", "test_sweep.py", "test_suite.py", "test_clock.py",
                 "test_receiver.py",
                 "test_sitl_gps.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))   # stable: each file keeps its own order

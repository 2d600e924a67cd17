"""Worker threads for the numba kernels, which release the GIL.

Channels (and the canceller's tracks) are independent of one another, so running them at once changes no result,
only the wall time.
"""

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

MAX_WORKERS = 4
T, R = TypeVar("T"), TypeVar("R")
_POOL: ThreadPoolExecutor | None = None


def cores() -> int:
    """The cores this process may run on (a container's CPU set, not the host's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


def run_each(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """fn over items, on up to MAX_WORKERS threads; results in the items' order."""
    items = list(items)
    if len(items) < 2 or cores() < 2:
        return [fn(item) for item in items]
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=min(MAX_WORKERS, cores()), thread_name_prefix="semperfi")
    return list(_POOL.map(fn, items))

"""Worker threads for the numba kernels, which release the GIL, and the per-thread scratch buffers they reuse.

Channels (and the canceller's tracks) are independent of one another, so running them at once changes no result,
only the wall time.
"""

import os
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

import numpy as np

MAX_WORKERS = 4
T, R = TypeVar("T"), TypeVar("R")
_POOL: ThreadPoolExecutor | None = None


THREADS_ENV = "SEMPERFI_THREADS"   # at most this many threads (the test suite's workers share the cores between them)


def cores() -> int:
    """The cores this process may run on (a container's CPU set, not the host's count), at most $SEMPERFI_THREADS."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        n = os.cpu_count() or 1
    cap = os.environ.get(THREADS_ENV, "")
    return max(1, min(n, int(cap))) if cap.isdigit() and int(cap) > 0 else n


def run_each(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """fn over items, on up to MAX_WORKERS threads; results in the items' order."""
    items = list(items)
    if len(items) < 2 or cores() < 2:
        return [fn(item) for item in items]
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=min(MAX_WORKERS, cores()), thread_name_prefix="semperfi")
    return list(_POOL.map(fn, items))


_ASIDE: ThreadPoolExecutor | None = None


def run_aside(fn: Callable[..., R], *args) -> Future:
    """fn(*args) on a thread of its own beside the workers (which it may use), for work whose result the caller
    collects later (future.result()): one such call at a time, in the order asked."""
    global _ASIDE
    if _ASIDE is None:
        _ASIDE = ThreadPoolExecutor(max_workers=1, thread_name_prefix="semperfi-aside")
    return _ASIDE.submit(fn, *args)


_LOCAL = threading.local()


def scratch(name: str, shape: tuple, dtype) -> np.ndarray:
    """A buffer of this thread's, reused from call to call until the next call with the same name: where malloc
    hands big arrays back to the system (glibc's default, unless cli._tune_heap ran), a fresh array of megabytes per
    call costs a page fault per 4 KiB."""
    buffers = getattr(_LOCAL, "buffers", None)
    if buffers is None:
        buffers = _LOCAL.buffers = {}
    size = int(np.prod(shape))
    buf = buffers.get(name)
    if buf is None or buf.size < size or buf.dtype != np.dtype(dtype):
        buf = buffers[name] = np.empty(size, dtype=dtype)
    return buf[:size].reshape(shape)

"""The local process pool of the evaluation's grids: spawned workers that leave nothing running behind them.

A grid's cell runs for minutes and starts programs of its own (gps-sdr-sim, `semperfi clean`, GNSS-SDR). Killed
with SIGTERM, a plain ProcessPoolExecutor's parent dies alone: its workers finish their cells, start the next ones
and keep both cores for an hour. Here each worker leads a process group of its own (it and the programs it starts),
and the parent, stopped by SIGTERM, Ctrl-C or an error, ends every group before it goes, and the group of every
program below a worker that left it (GNSS-SDR runs in a session of its own).
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from multiprocessing import get_context
from pathlib import Path


class _Terminated(KeyboardInterrupt):
    """SIGTERM reached the pool's parent: stopped from outside, as by Ctrl-C (and handled where Ctrl-C is)."""


def _on_sigterm(signum, frame):
    raise _Terminated("terminated")


def _descendants(pids: set[int]) -> set[int]:
    """Every process below these, from /proc (none where there is no /proc): a program that runs in a session of
    its own (GNSS-SDR, so that run_gnss_sdr can stop its whole group) has left its worker's group, not its tree."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue   # gone meanwhile
        children.setdefault(ppid, []).append(int(stat.parent.name))
    found: set[int] = set()
    todo = list(pids)
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def _end_groups(pool: ProcessPoolExecutor) -> None:
    """SIGTERM to every worker's group and to the group of every program below a worker (a worker killed alone left
    GNSS-SDR, in a session of its own, running its file without a parent)."""
    # the executor keeps its workers' processes by pid and offers no public way to stop them
    workers = set(getattr(pool, "_processes", None) or {})
    groups = set(workers)
    for pid in _descendants(workers):
        try:
            groups.add(os.getpgid(pid))
        except ProcessLookupError:
            pass
    groups.discard(os.getpgrp())
    for pgid in groups:
        try:
            os.killpg(pgid, signal.SIGTERM)
        except (ProcessLookupError, PermissionError):
            pass   # gone already


@contextmanager
def worker_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A ProcessPoolExecutor of spawned workers (a forked child would inherit the parent's numba and BLAS threads
    mid-flight), each a process group's leader; left by an exception, Ctrl-C or SIGTERM (raised as _Terminated in the
    main thread), every group is sent SIGTERM and the work not started is dropped."""
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if main else None
    pool = ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=os.setpgrp)
    try:
        yield pool
    except BaseException:
        _end_groups(pool)
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    else:
        pool.shutdown()
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous)

"""The local process pool of the evaluation's grids: spawned workers that leave nothing running behind them.

A grid's cell runs for minutes and starts programs of its own (gps-sdr-sim, `semperfi clean`, GNSS-SDR). Killed
with SIGTERM, a plain ProcessPoolExecutor's parent dies alone: its workers finish their cells, start the next ones
and keep both cores for an hour. Here each worker leads a process group of its own (it and the programs it starts),
and the parent, stopped by SIGTERM, Ctrl-C or an error, ends every group before it goes.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from multiprocessing import get_context


class _Terminated(KeyboardInterrupt):
    """SIGTERM reached the pool's parent: stopped from outside, as by Ctrl-C (and handled where Ctrl-C is)."""


def _on_sigterm(signum, frame):
    raise _Terminated("terminated")


def _start_worker() -> None:
    """A worker leads its own process group (the parent ends it whole), and SIGTERM unwinds its cell like Ctrl-C: a
    program that runs in a session of its own (GNSS-SDR: run_gnss_sdr stops its group on the way out) is not in the
    group, and a worker killed outright left it running without a parent."""
    os.setpgrp()
    signal.signal(signal.SIGTERM, _on_sigterm)


def _end_groups(pool: ProcessPoolExecutor) -> None:
    # the executor keeps its workers' processes by pid and offers no public way to stop them
    for pid in list(getattr(pool, "_processes", None) or {}):
        try:
            os.killpg(pid, signal.SIGTERM)
        except (ProcessLookupError, PermissionError):
            pass   # gone already


@contextmanager
def worker_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A ProcessPoolExecutor of spawned workers (a forked child would inherit the parent's numba and BLAS threads
    mid-flight), each a process group's leader; left by an exception, Ctrl-C or SIGTERM (raised as _Terminated in the
    main thread), every group is sent SIGTERM and the work not started is dropped."""
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if main else None
    pool = ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_start_worker)
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

"""SemperFi's exceptions, under one base, so that the command line tells a user's mistake from a bug in one place."""

import traceback


class SemperFiError(Exception):
    """Anything SemperFi reports to its user as one line."""

    exit_code = 2


class InternalError(SemperFiError):
    """A bug met while processing: the outputs written so far are kept, the event log says where."""

    exit_code = 70   # EX_SOFTWARE (sysexits.h)


def describe(exc: BaseException) -> dict:
    """What an internal_error event records to reproduce a failure: the exception and the innermost frame of ours."""
    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return {"error": f"{type(exc).__name__}: {exc}", "where": "?"}
    f = frames[-1]   # where it was raised
    name = f.filename.rsplit("semperfi/", 1)[-1] if "semperfi/" in f.filename else f.filename.rsplit("/", 1)[-1]
    return {"error": f"{type(exc).__name__}: {exc}", "where": f"{name}:{f.lineno} in {f.name}"}


def log_internal_error(events, t_s: float, exc: BaseException) -> str:
    """An internal error as an `internal_error` event (events.emit) and the one line to report it with."""
    what = describe(exc)
    events.emit("internal_error", t_s, **what)
    return f"{what['error']} (at {what['where']}, t = {t_s:.2f} s)"

"""SemperFi's exceptions, under one base, so that the command line tells a user's mistake from a bug in one place."""

import traceback


# What every command's exit code says (README, "Exit codes"): the one table of them.
EXIT_BAD_INPUT = 2     # a user's mistake or an input that cannot be read: one line says which
EXIT_NO_SIGNAL = 3     # the input was read but held no GPS signal to track (a wrong --fs/--format/--if, or jamming)
EXIT_INPUT_SHORT = 4   # the input ended before the window asked for, or mid-sample: all of it was processed
EXIT_INPUT_LOST = 5    # the input stalled or closed part-way: what came before is processed and written
EXIT_INTERNAL = 70     # EX_SOFTWARE (sysexits.h): a bug; outputs kept, the event log says where
EXIT_INTERRUPTED = 130   # the shell's code for a run stopped by Ctrl-C (128 + SIGINT)


class SemperFiError(Exception):
    """Anything SemperFi reports to its user as one line."""

    exit_code = EXIT_BAD_INPUT


class BadInput(SemperFiError, ValueError):
    """An input that cannot be used as given: a user's mistake, or a file, stream, peer or tool that failed or sent
    what cannot be (hostile or broken, told apart by the message, not the exit code)."""


class NoSignal(SemperFiError, ValueError):
    """Nothing could be tracked: almost always a wrong sample rate, format or IF, else interference."""

    exit_code = EXIT_NO_SIGNAL


class InternalError(SemperFiError):
    """A bug met while processing: the outputs written so far are kept, the event log says where."""

    exit_code = EXIT_INTERNAL


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

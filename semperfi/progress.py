"""The progress bar of a long command on a terminal (rich, on stderr: stdout stays the command's answer)."""

from typing import Iterable, Iterator


def progress(items: Iterable, total: int | None, what: str, shown: bool = True) -> Iterator:
    """items, drawing a bar of how many of total are done (a spinner when total is None) while shown."""
    if not shown:
        yield from items
        return
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TaskProgressColumn,
                               TextColumn, TimeRemainingColumn)
    columns = (TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(), MofNCompleteColumn(),
               TimeRemainingColumn()) if total is not None else (SpinnerColumn(), TextColumn("{task.description}"),
                                                                  TextColumn("{task.completed} done"))
    with Progress(*columns, console=Console(stderr=True), transient=False) as bar:
        task = bar.add_task(what, total=total)
        for item in items:
            yield item
            bar.advance(task)

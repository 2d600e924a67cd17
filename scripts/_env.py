"""What every script here checks first: that it runs on an interpreter with the project installed. Run with another
(`scripts/X` picks the first python3 on PATH), a missing dependency was a traceback; now it is one line."""

import sys
from pathlib import Path


def require_project(script: str) -> None:
    """Exit with one line naming the missing module and the interpreter to use, when semperfi cannot be imported."""
    try:
        import semperfi  # noqa: F401
    except ImportError as exc:
        name = Path(script).name
        sys.exit(f"{name}: {exc.name or exc} is not installed for {sys.executable}: run it with the project's "
                 f"environment, e.g. .venv/bin/python scripts/{name} (README: the first command makes .venv)")

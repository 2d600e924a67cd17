"""The repository's scripts/ (they have no .py suffix), imported by the tests."""

import importlib.machinery
import importlib.util
from pathlib import Path


def load_script(name: str):
    """scripts/NAME as a module."""
    path = Path(__file__).parents[1] / "scripts" / name
    module_name = name.replace("-", "_")
    loader = importlib.machinery.SourceFileLoader(module_name, str(path))
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(module_name, loader))
    loader.exec_module(module)
    return module

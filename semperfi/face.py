"""A room's public face: the names other rooms use, each from the module that defines it, imported only when first
asked for (PEP 562), so that using one name of a room does not load all of it (its numba kernels, scipy)."""

import importlib
import sys


def lazy_face(package: str, modules: dict[str, tuple[str, ...]]):
    """(__all__, __getattr__, __dir__) for a room's __init__: `modules` maps each of the room's modules to the
    names it gives the face."""
    home = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name: str):
        if name not in home:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{home[name]}"), name)
        setattr(sys.modules[package], name, value)   # the next lookup is a plain attribute
        return value

    def __dir__():
        return sorted(home)

    return sorted(home), __getattr__, __dir__

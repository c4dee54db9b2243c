"""A package's public surface re-exported lazily (PEP 562): the package's ``__init__`` names each public name and the
module that defines it, and a name's module is imported when the name is first used, so importing the package costs
no more than the modules a caller asks for.

    from pihutil.lazy import lazy_exports

    EXPORTS = {"Task": "envs.task.task", "preset": "envs.task.task"}
    __all__ = sorted(EXPORTS)
    __getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
"""

from __future__ import annotations

import importlib
import sys
from typing import Any, Callable, Mapping


def lazy_exports(package: str, exports: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of ``package`` for the names of ``exports`` (name -> the module,
    or the package re-exporting it, where it is found): the first ``package.NAME`` (or ``from package import NAME``)
    imports that module, takes its NAME and keeps it in the package, so later lookups do not come back here.

    The returned ``__getattr__`` raises AttributeError for a name not in ``exports``, as Python does for a module
    without the attribute (``from package import submodule`` then imports the submodule, as usual).
    """
    table = dict(exports)

    def __getattr__(name: str) -> Any:
        try:
            module = table[name]
        except KeyError:
            raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(table))

    return __getattr__, __dir__

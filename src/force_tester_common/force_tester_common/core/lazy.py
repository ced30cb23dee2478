"""Package exports imported on first use (PEP 562), so that importing one submodule of a package
does not import all of them: `./ft bag correct` and every --help start without the modules they
do not need."""
from __future__ import annotations

import importlib
import sys


def lazy_exports(package: str, exports: dict) -> tuple:
    """A package's (__getattr__, __dir__) for EXPORTS, {name: submodule}: the submodule is imported
    when the name is first used, and the name is kept in the package from then on."""
    def __getattr__(name: str):
        submodule = exports.get(name)
        if submodule is None:
            raise AttributeError(f'module {package!r} has no attribute {name!r}')
        value = getattr(importlib.import_module(f'{package}.{submodule}'), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list:
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return __getattr__, __dir__

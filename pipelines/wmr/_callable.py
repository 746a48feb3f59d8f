"""Modules that are also the API function of their name (``wmr.run(...)``).

``wmr.run``, ``wmr.batch`` and ``wmr.optimal`` are modules of the library, and Python sets a
package's attribute to its submodule once that is imported, so a function of the same name in
``wmr`` would be replaced as soon as any code imports the module.  Instead, each of these
modules calls :func:`make_callable` on itself: calling the module calls the function of
:mod:`wmr.api`, while ``from wmr.run import run_to_log`` keeps working.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any


class _CallableModule(types.ModuleType):
    """A module whose call is ``wmr.api.<its last name>``."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        api = importlib.import_module("wmr.api")
        return getattr(api, self.__name__.rsplit(".", 1)[1])(*args, **kwargs)


def make_callable(module_name: str) -> None:
    """Make the (imported) module ``module_name`` callable as its API function."""
    sys.modules[module_name].__class__ = _CallableModule


__all__ = ["make_callable"]

"""Plug-ins from other installed packages: the entry points of one group, found and loaded lazily.

An installed distribution declares an entry point in a group (``wmr.controllers``:
``[project.entry-points."wmr.controllers"]`` in its ``pyproject.toml``); :func:`entry_points`
lists the group's entry points by name without importing anything (it reads the installed
distributions' ``entry_points.txt``), and :func:`load` imports one when it is used.  A plug-in
that fails to import is one :class:`PluginError` line naming its package and its entry point,
raised only when that plug-in is asked for: a broken plug-in never stops a command that does
not use it.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # importlib.metadata is imported when a group is first listed, not before
    from importlib import metadata


class PluginError(Exception):
    """A plug-in cannot be loaded or is not what its group expects (one line).

    The caller turns it into the error of the field that named the plug-in.
    """


def _package(ep: metadata.EntryPoint) -> str:
    """The name of the distribution that declares ``ep`` (``?`` when unknown)."""
    dist = getattr(ep, "dist", None)
    name = getattr(dist, "name", None) if dist is not None else None
    return str(name) if name else "?"


def describe(ep: metadata.EntryPoint) -> str:
    """``entry point NAME = VALUE of package PKG``: how an error names a plug-in."""
    return f"entry point {ep.name} = {ep.value} of package {_package(ep)}"


@cache
def entry_points(group: str) -> dict[str, tuple[metadata.EntryPoint, ...]]:
    """The entry points of ``group`` by name, nothing imported (found once per process).

    A name that two installed packages declare maps to both (the caller refuses it when it
    is used).
    """
    from importlib import metadata

    found: dict[str, list[metadata.EntryPoint]] = {}
    for ep in metadata.entry_points(group=group):
        same = found.setdefault(ep.name, [])
        if all(e.value != ep.value or _package(e) != _package(ep) for e in same):
            same.append(ep)  # the same distribution seen twice on the path counts once
    return {name: tuple(eps) for name, eps in sorted(found.items())}


def load(ep: metadata.EntryPoint) -> object:
    """Import the object of ``ep``.

    Raises
    ------
    PluginError
        Whatever the import raised, as one line naming the package and the entry point.
    """
    try:
        return ep.load()
    except Exception as exc:  # a plug-in's own bug: named, never a traceback from wmr
        detail = " ".join(str(exc).split())[:200]
        raise PluginError(f"{describe(ep)} failed to load: {type(exc).__name__}: "
                          f"{detail}") from None


__all__ = ["PluginError", "describe", "entry_points", "load"]

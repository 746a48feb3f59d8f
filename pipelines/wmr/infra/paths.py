"""Where the project's non-Python sources live, in a checkout and in an installed wheel."""

from __future__ import annotations

import os
import re
from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent.parent
_REPO_ROOT = _PACKAGE_DIR.parent.parent


def _resource(relative: str) -> Path:
    """Return ``relative`` from the wheel's ``_data`` folder, else from the source checkout."""
    installed = _PACKAGE_DIR / "_data" / relative
    if installed.exists():
        return installed
    return _REPO_ROOT / relative


def modelica_dir() -> Path:
    """Folder that holds the ``WMR`` Modelica package."""
    return _resource("modelica")


def fmu_src_dir() -> Path:
    """Folder of the hand-written C sources of the FMUs (FMI layer, solver, contract)."""
    return _resource("fmu/src")


def license_file() -> Path:
    """The project's licence (BSD-2-Clause), shipped inside every FMU."""
    return _resource("LICENSE")


def scenarios_dir() -> Path:
    """Folder of the scenario files shipped with the project (the paper's Section 5)."""
    return _resource("scenarios")


def cache_dir() -> Path:
    """Per-user cache for built FMUs; ``WMR_CACHE_DIR`` overrides it."""
    env = os.environ.get("WMR_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "wmr-cosim"


def default_fmu_dir() -> Path:
    """Where ``wmr fmu build`` writes when ``--out`` is not given."""
    return cache_dir() / "fmu"


def safe_filename(name: str) -> str:
    """A run name as a file name, one-to-one: two names never give the same file.

    Letters, digits, ``-``, ``_``, ``.``, ``+`` and ``=`` are kept; any other character (``/``,
    a space, ``%`` itself), and a leading ``.`` (``.``, ``..``, hidden files), is written
    ``%XX`` per UTF-8 byte, as in URLs; the empty name is ``%``.
    """
    def escape(match: re.Match[str]) -> str:
        return "".join(f"%{b:02X}" for b in match.group().encode("utf-8"))

    if not name:
        return "%"
    return re.sub(r"^\.|[^A-Za-z0-9_.+=-]", escape, name)

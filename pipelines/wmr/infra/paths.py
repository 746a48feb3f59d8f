"""Where the project's non-Python sources live, in a checkout and in an installed wheel."""

from __future__ import annotations

import hashlib
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


#: Longest file name stem :func:`safe_filename` makes, in bytes *after* percent-encoding (one
#: ``é`` is 6 bytes, ``%C3%A9``; one emoji 12): file systems allow 255 bytes (``NAME_MAX``), and
#: the longest suffix put after a stem is 24 (a run log's ``.mcap.partial.recovering``).
MAX_STEM_BYTES = 200
#: Hex digits of the hash that ends a cut stem.
_HASH_CHARS = 10
_KEPT = re.compile(r"[A-Za-z0-9_.+=-]")


def _escaped(char: str, first: bool) -> str:
    if _KEPT.fullmatch(char) and not (first and char == "."):
        return char
    return "".join(f"%{b:02X}" for b in char.encode("utf-8", "surrogatepass"))


def safe_filename(name: str, max_bytes: int = MAX_STEM_BYTES) -> str:
    """A run (or scenario, case) name as a file name stem, one-to-one: two names never give
    the same file, and every file system takes it with a suffix of up to 55 bytes.

    Letters, digits, ``-``, ``_``, ``.``, ``+`` and ``=`` are kept; any other character (``/``,
    a space, ``%`` itself, ``~``), and a leading ``.`` (``.``, ``..``, hidden files), is written
    ``%XX`` per UTF-8 byte, as in URLs; the empty name is ``%``.  A stem longer than
    ``max_bytes`` is cut at a character (never inside its ``%XX`` escapes) and ended with
    ``~`` and a hash of the whole name: two long names stay apart, and a cut stem is never
    another name's whole one (a name's own ``~`` is escaped).  The one place where a name
    becomes a file name: run logs, scenario attachments, ``.ssp`` packages, ``.rrd`` files
    and figure logs all come from here.
    """
    if not name:
        return "%"
    pieces = [_escaped(c, i == 0) for i, c in enumerate(name)]
    if sum(len(p) for p in pieces) <= max_bytes:  # the pieces are ASCII: chars are bytes
        return "".join(pieces)
    digest = hashlib.sha256(name.encode("utf-8", "surrogatepass")).hexdigest()[:_HASH_CHARS]
    budget = max_bytes - len(digest) - 1
    kept: list[str] = []
    for piece in pieces:
        if budget < len(piece):
            break
        kept.append(piece)
        budget -= len(piece)
    return f"{''.join(kept)}~{digest}"

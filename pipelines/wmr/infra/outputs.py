"""The one check of an output path, made by every command before any work.

A command that would only fail when it writes (an output under a regular file, in a folder
that cannot be written, a file where a folder is wanted) refuses at once with one line that
names the option, instead of an internal error, or a failure after minutes of computation.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from wmr.infra.errors import ConfigError


def _nearest_existing(path: Path) -> Path:
    for parent in (path, *path.parents):
        if parent.exists() or parent.is_symlink():
            return parent
    return Path(".")


def check_output(path: str | os.PathLike[str], option: str,
                 kind: Literal["file", "dir"] = "file", suffix: str | None = None) -> Path:
    """Return ``path`` if the command can write it, else raise a :class:`ConfigError`.

    Parameters
    ----------
    path
        The file (or folder) the command will write; it and its parents may not exist yet.
    option
        The command-line option that gave it (``--out``), named in the error.
    kind
        ``"file"``: a file (an existing folder there is refused); ``"dir"``: a folder.
    suffix
        The file name's required ending (``".mcap"``), or None.
    """
    p = Path(path)
    if suffix is not None and p.suffix != suffix:
        raise ConfigError(option, f"{p} must end in {suffix}", f"give FILE{suffix}")
    if kind == "file" and p.is_dir():
        raise ConfigError(option, f"{p} is a folder", "give a file name")
    if kind == "dir" and p.exists() and not p.is_dir():
        raise ConfigError(option, f"{p} is a file, not a folder", "give a folder")
    base = _nearest_existing(p.parent if kind == "file" else p)
    if not base.is_dir():
        raise ConfigError(option, f"{p} would be under {base}, which is a file, not a folder",
                          "give a path in a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise ConfigError(option, f"cannot write in {base} (permission denied)",
                          "give a folder you can write")
    if p.exists() and not os.access(p, os.W_OK):
        raise ConfigError(option, f"{p} exists and cannot be overwritten (permission denied)",
                          "give another path")
    return p


__all__ = ["check_output"]

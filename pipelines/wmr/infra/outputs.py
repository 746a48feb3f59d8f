"""The one check of an output path, made by every command before any work.

A command that would only fail when it writes (an output under a regular file, in a folder
that cannot be written, a file where a folder is wanted) refuses at once with one line that
names the option, instead of an internal error, or a failure after minutes of computation.
An output that exists and is a device, a FIFO or a socket is refused too, even with
``--force``: wmr would replace it by a regular file (:func:`refuse_special`).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Literal

from wmr.infra.errors import ConfigError
from wmr.infra.inputs import file_kind


def _nearest_existing(path: Path) -> Path:
    for parent in (path, *path.parents):
        if parent.exists() or parent.is_symlink():
            return parent
    return Path(".")


def refuse_special(path: str | os.PathLike[str], option: str | None = None,
                   kind: Literal["file", "dir"] = "file") -> None:
    """Refuse an output ``path`` that exists and is not what wmr writes there: a regular file
    (``kind="file"``) or a folder (``"dir"``), a symbolic link followed.  Overwriting allowed
    (``--force``) or not: wmr replaces a file it writes by a rename, which would replace a
    device node or a FIFO (as root, ``/dev/null`` itself) by a regular file.

    Every writer calls this (through :func:`check_output` for an option, and
    :class:`wmr.infra.durable.AtomicFile` and :func:`wmr.infra.durable.replacing` once more
    before they create or rename anything).

    Parameters
    ----------
    path
        The output.
    option
        The option that gave it, named first in the error; default ``output``.
    kind
        What the output is.

    Raises
    ------
    ConfigError
        One line naming the option, the file and what it is.
    """
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except OSError:  # missing, a dangling link (replaced, its target untouched), unreachable
        return
    if (stat.S_ISDIR(mode) if kind == "dir" else stat.S_ISREG(mode)):
        return
    # the path goes in the problem, never as the field: an error line cuts a field at 80
    # characters, which left a long path's middle out ("/tmp/... (94 characters) ...png")
    named = f"{p} "
    if kind == "dir":
        problem = "is a file, not a folder" if stat.S_ISREG(mode) else \
            f"is {file_kind(mode)}, not a folder"
        fix = "give a folder"
    elif stat.S_ISDIR(mode):
        problem, fix = "is a folder", "give a file name"
    else:
        problem = (f"is {file_kind(mode)}, not a regular file: wmr would replace it by a file, "
                   "even with --force")
        fix = "give the path of a regular file"
    raise ConfigError("output" if option is None else option, f"{named}{problem}", fix)


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
    refuse_special(p, option, kind)
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


__all__ = ["check_output", "refuse_special"]

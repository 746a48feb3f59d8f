"""Whether a cached file may be used: only if no one but this user (or root) can have written
it, as OpenSSH treats ``~/.ssh``.

wmr loads libraries from its cache (the C stepper, the FMUs it built): a file there is used only
if it, and every folder above it up to the cache's root, is owned by this user or root, is
writable by no one else, and is no symbolic link; the folders above the root are owned by this
user or root and writable by no one else unless sticky (``/tmp``).  Cache folders are made
with mode 0700 whatever the umask.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from wmr.infra import paths


def _owner_problem(st: os.stat_result) -> str | None:
    if st.st_uid not in (os.geteuid(), 0):
        return f"is owned by uid {st.st_uid}, not by you (uid {os.geteuid()})"
    return None


def untrusted(path: Path, root: Path) -> str | None:
    """Why ``path`` (at or under the folder ``root``) must not be used, or None if it may.

    ``path`` and each folder between it and ``root`` (both included) must be no symbolic link,
    owned by this user or root, and not writable by group or others; the folders above
    ``root`` (its real path's) owned by this user or root and not writable by group or others,
    unless sticky.  Parts that do not exist yet are skipped: there is nothing in them to use.

    Returns
    -------
    str | None
        ``"<path>: <problem>"``, one line, for the first part that fails.
    """
    path, root = Path(os.path.abspath(path)), Path(os.path.abspath(root))
    if path != root and root not in path.parents:
        return f"{path}: is not inside {root}"
    at = path
    while True:
        try:
            st = os.lstat(at) if at != root else os.stat(at)
        except FileNotFoundError:
            st = None
        if st is not None:
            if stat.S_ISLNK(st.st_mode):
                return f"{at}: is a symbolic link"
            problem = _owner_problem(st)
            if problem is None and st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
                problem = (f"is writable by other users (mode {stat.S_IMODE(st.st_mode):o})")
            if problem is not None:
                return f"{at}: {problem}"
        if at == root:
            break
        at = at.parent
    for above in Path(os.path.realpath(root)).parents:
        st = os.stat(above)
        problem = _owner_problem(st)
        if problem is None and st.st_mode & (stat.S_IWGRP | stat.S_IWOTH) \
                and not st.st_mode & stat.S_ISVTX:
            problem = f"is writable by other users (mode {stat.S_IMODE(st.st_mode):o})"
        if problem is not None:
            return f"{above}: {problem}"
    return None


def trust_root(folder: Path) -> Path:
    """The root up to which the entries of ``folder`` are checked: the cache
    (:func:`wmr.infra.paths.cache_dir`) for a folder in it, else ``folder`` itself."""
    cache = Path(os.path.abspath(paths.cache_dir()))
    folder = Path(os.path.abspath(folder))
    return cache if folder == cache or cache in folder.parents else folder


def make_folder(folder: Path, root: Path, mode: int = 0o700) -> None:
    """Make ``folder`` and the missing folders above it with ``mode`` (0700: only this user);
    ``os.mkdir`` with an explicit mode, which a umask can narrow but never widen (``umask
    000`` made ``Path.mkdir``'s folders 0777).  ``root``'s own parents are made 0755 when
    missing, as ``mkdir -p`` would under the usual umask.

    Raises
    ------
    OSError
        As ``os.mkdir``.
    """
    folder, root = Path(os.path.abspath(folder)), Path(os.path.abspath(root))
    missing = []
    at = folder
    while not at.exists() and at != at.parent:
        missing.append(at)
        at = at.parent
    for part in reversed(missing):
        inside = part == root or root in part.parents
        try:
            os.mkdir(part, mode if inside else 0o755)
        except FileExistsError:  # made meanwhile by another process: checked by the caller
            pass


__all__ = ["make_folder", "trust_root", "untrusted"]

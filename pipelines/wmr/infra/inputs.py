"""The one way wmr opens a file it reads as input: a scenario, a batch spec, a variable map,
an FMU (to hash or unpack it), tuned gains.

An input is opened with ``O_NONBLOCK`` and checked with ``fstat`` before any byte is read: a
FIFO would otherwise block the open until a writer came, ``/dev/zero`` would be read until the
memory ran out, and a folder fails with an error that does not say what was wrong.  Anything but
a regular file is refused in one line naming the file and what it is; a regular file is read
no further than a limit named, with its value, in the refusal.
"""

from __future__ import annotations

import hashlib
import io
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Final

from wmr.infra.errors import ConfigError

MiB: Final = 1 << 20
#: The most wmr reads of a TOML input (scenario, batch spec, variable map).  A scenario of
#: 200,000 ``[[runs]]`` is 5 MB; past this limit a file is a mistake (or ``/dev/zero``).
MAX_TOML_BYTES: Final = 64 * MiB
#: The most wmr reads of an FMU archive (hashed, or opened to unpack).  An archive unpacks to
#: at most 512 MiB (``wmr.adapters.fmi.archive.MAX_UNCOMPRESSED_BYTES``), and a zip is never
#: much larger than what it holds: a larger file could not be unpacked anyway.
MAX_ARCHIVE_BYTES: Final = 1024 * MiB
#: The most wmr reads of a small JSON input (``--tuned``).
MAX_JSON_BYTES: Final = 16 * MiB

_CHUNK: Final = MiB

#: What a file that is not a regular file is, by its mode, for the one line that refuses it.
_KINDS: Final[tuple[tuple[Callable[[int], bool], str], ...]] = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words (``"a named pipe (FIFO)"``);
    ``"a regular file"`` for one."""
    if stat.S_ISREG(mode):
        return "a regular file"
    return next((kind for test, kind in _KINDS if test(mode)), "not a regular file")


def _size_words(n_bytes: int) -> str:
    """``n_bytes`` in bytes, and in MiB when it is a whole number of them (``64 MiB``)."""
    if n_bytes >= MiB and n_bytes % MiB == 0:
        return f"{n_bytes} bytes ({n_bytes // MiB} MiB)"
    return f"{n_bytes} bytes"


def _named(path: Path, field: str) -> str:
    """``path`` as the start of a problem, or nothing when ``field`` already is the path."""
    return "" if field == str(path) else f"{path} "


def too_large(path: Path, field: str, max_bytes: int, what: str, fix: str) -> ConfigError:
    """The one line refusing an input larger than ``max_bytes``."""
    return ConfigError(field, f"{_named(path, field)}is larger than {_size_words(max_bytes)}, "
                       f"the most wmr reads of {what}", fix)


def open_input(path: str | os.PathLike[str], field: str, *, max_bytes: int,
               what: str = "a file", fix: str = "give a regular file") -> io.BufferedReader:
    """Open the input ``path`` for reading (a binary file, to close), refusing what is not a
    regular file of at most ``max_bytes`` (its size now).

    Parameters
    ----------
    path
        The file; a symbolic link is followed.
    field
        The field or option that named it (``"scenario"``, ``"--map"``), first in an error;
        the path itself when nothing else names it.
    max_bytes
        The limit on its size, named with its value in the refusal.
    what
        What the file is, for the refusal of a large one (``"a scenario"``).
    fix
        What to do instead, for the refusal of a file that is not a regular file or too large.

    Raises
    ------
    FileNotFoundError
        There is no such file: the caller says what it expected there.
    ConfigError
        It is a folder, FIFO, device or socket; it is larger than ``max_bytes``; it cannot be
        opened (permissions, ...): one line naming ``field``, the file and the reason.
    """
    p = Path(path)
    try:
        # O_NONBLOCK: a FIFO opens at once (it would wait for a writer), to be refused below
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise ConfigError(field, f"cannot read {p}: {exc.strerror}",
                          "check the path and its permissions") from None
    except ValueError:  # a NUL byte in the path
        raise ConfigError(field, f"{str(p)!r} is not a file name (it holds a NUL byte)",
                          fix) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError(field, f"{_named(p, field)}is {file_kind(st.st_mode)}, not a "
                              "regular file", fix)
        if st.st_size > max_bytes:
            raise too_large(p, field, max_bytes, what, fix)
    except BaseException:
        os.close(fd)
        raise
    return open(fd, "rb")


def read_input(path: str | os.PathLike[str], field: str, *, max_bytes: int,
               what: str = "a file", fix: str = "give a regular file") -> bytes:
    """The bytes of the input ``path``, at most ``max_bytes`` of them, through
    :func:`open_input` (same parameters and errors).  A file that grows past the limit while
    it is read (or one whose size says 0, as in ``/proc``) is refused, not read on."""
    with open_input(path, field, max_bytes=max_bytes, what=what, fix=fix) as stream:
        data = stream.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise too_large(Path(path), field, max_bytes, what, fix)
    return data


def sha256_input(path: str | os.PathLike[str], field: str, *, max_bytes: int,
                 what: str = "a file", fix: str = "give a regular file") -> str:
    """The SHA-256 (hex) of the input ``path``, read a chunk at a time and no further than
    ``max_bytes``, through :func:`open_input` (same parameters and errors)."""
    digest = hashlib.sha256()
    buf = bytearray(_CHUNK)
    view = memoryview(buf)
    total = 0
    with open_input(path, field, max_bytes=max_bytes, what=what, fix=fix) as stream:
        while n := stream.readinto(view):
            total += n
            if total > max_bytes:
                raise too_large(Path(path), field, max_bytes, what, fix)
            digest.update(view[:n])
    return digest.hexdigest()


__all__ = ["MAX_ARCHIVE_BYTES", "MAX_JSON_BYTES", "MAX_TOML_BYTES", "file_kind", "open_input",
           "read_input", "sha256_input", "too_large"]

"""Writing files so that a crash, a second writer or a full disk never damages a finished one.

A finished file is replaced only by another finished file: :class:`AtomicFile` writes to
``NAME.partial`` in the same folder (locked against a second writer), and :meth:`commit
<AtomicFile.commit>` fsyncs it and renames it over ``NAME`` (then fsyncs the folder), the way
SQLite and rosbag2 keep a committed file whole.  A process killed before the commit leaves
``NAME`` as it was and its own data in ``NAME.partial``, which ``wmr log recover`` reads.

No write can be redirected by a file someone planted: ``NAME.partial`` is opened with
``O_NOFOLLOW`` and refused (one :class:`~wmr.infra.errors.LogError` line) when it is a
symbolic link, a hard link, not a regular file or another user's; any other temporary file
(:func:`replacing`, :func:`replacing_path`) gets a new random name, created ``O_CREAT |
O_EXCL | O_NOFOLLOW``.  A final file is only ever renamed over, never written through.

Every write checks its result: :func:`write_all` loops over short writes of ``os.write``, and
a full disk (``ENOSPC``, ``EDQUOT``) becomes one :class:`~wmr.infra.errors.DiskFullError` line
naming the device and the file.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import os
import secrets
import signal
import stat
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO, Final

from wmr.infra.errors import DiskFullError, LogError
from wmr.infra.outputs import refuse_special

#: Suffix of a file being written (or left by a killed writer).
PARTIAL_SUFFIX: Final = ".partial"
_FULL: Final = (errno.ENOSPC, errno.EDQUOT)


#: Holds in force (:func:`stop_signals_held`), and the stop signal that came during them.
_holds = 0
_held_signal: int | None = None


def stop_signal_held(signum: int) -> bool:
    """For a stop signal's handler: whether a file is being finished (:func:`stop_signals_held`),
    so that the signal must wait; it is then delivered again when the file is whole."""
    global _held_signal
    if _holds == 0:
        return False
    if _held_signal is None:
        _held_signal = signum
    return True


@contextmanager
def stop_signals_held() -> Iterator[None]:
    """Hold a stop signal (SIGINT, SIGTERM) back while a file is finished, then deliver it.

    The command line's handler raises in the main thread at the next bytecode, wherever that
    is: in the last writes of a log whose run has ended, it would leave the log unfinished (its
    ``.partial``), though nothing was left to stop. Its handler asks :func:`stop_signal_held`
    first; a held signal is raised again (``signal.raise_signal``) when the outermost hold
    ends, so the log is whole, with its own result, and the command then stops as asked.
    """
    global _holds, _held_signal
    _holds += 1
    try:
        yield
    finally:
        _holds -= 1
        if _holds == 0 and _held_signal is not None:
            signum, _held_signal = _held_signal, None
            signal.raise_signal(signum)


def partial_path(path: str | os.PathLike[str]) -> Path:
    """Where :class:`AtomicFile` writes ``path`` until it is complete."""
    p = Path(path)
    return p.with_name(p.name + PARTIAL_SUFFIX)


def mount_point(path: str | os.PathLike[str]) -> str:
    """The mount point holding ``path`` (the device a full disk is named by)."""
    p = Path(os.path.abspath(path))
    while not os.path.ismount(p) and p != p.parent:
        p = p.parent
    return str(p)


def storage_error(exc: OSError, path: str | os.PathLike[str]) -> OSError | DiskFullError:
    """``exc`` as a :class:`DiskFullError` when the disk is full, else ``exc`` itself."""
    # pyarrow raises OSError without an errno, with the C library's message
    if exc.errno in _FULL or os.strerror(errno.ENOSPC) in str(exc):
        err = DiskFullError(f"no space left on {mount_point(path)} while writing {path}")
        err.__cause__ = exc
        return err
    return exc


def write_all(fd: int, data: bytes, path: str | os.PathLike[str]) -> None:
    """Write all of ``data`` to ``fd``: ``os.write`` may write less than it was given.

    Raises
    ------
    DiskFullError
        The disk is full (nothing is retried: a full disk does not free itself).
    OSError
        Any other write error.
    """
    view = memoryview(data)
    while view:
        try:
            n = os.write(fd, view)
        except OSError as exc:
            raise storage_error(exc, path) from exc
        if n <= 0:  # a regular file never does this except on a full disk
            raise DiskFullError(f"no space left on {mount_point(path)} while writing {path}")
        view = view[n:]


def _writeback_starter() -> Callable[[int], object] | None:
    """Linux ``sync_file_range(fd, 0, 0, SYNC_FILE_RANGE_WRITE)``: start writing the dirty
    pages of a file to disk without waiting, so that the ``fsync`` of the commit has little
    left to do (a few ms instead of tens for a log of a few MB)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).sync_file_range
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return lambda fd: fn(fd, 0, 0, 2)  # a hint: its failure changes nothing


_start_writeback = _writeback_starter()
#: A durable file's pages are handed to the disk once this many bytes were flushed since the
#: last time (a bound on what the commit's ``fsync`` waits for).  Not at every flush: a call
#: costs about 50 us, and a run's log flushes every second of simulation time (1.3 us of a
#: 10 us logged step before; a shorter log is written out by its commit's ``fsync`` alone).
WRITEBACK_BYTES: Final = 8 << 20


def fsync_dir(folder: str | os.PathLike[str]) -> None:
    """Make a rename in ``folder`` durable (a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems refuse fsync on a folder; the rename still happened
        pass
    finally:
        os.close(fd)


def _refuse_foreign(path: Path, st: os.stat_result, what: str) -> None:
    """Refuse to write into a file that another user or process planted: not a regular file,
    a hard link to another file (writing would change that file too), or not ours."""
    problem = None
    if not stat.S_ISREG(st.st_mode):
        problem = "is not a regular file"
    elif st.st_nlink != 1:
        problem = f"has {st.st_nlink} names (a hard link: writing it would change another file)"
    elif st.st_uid != os.geteuid():
        problem = f"belongs to another user (uid {st.st_uid})"
    if problem is not None:
        raise LogError(f"{path}: {problem}; wmr never makes such a file: remove it, or write "
                       f"the {what} elsewhere")


def open_own(path: str | os.PathLike[str], flags: int, what: str, mode: int = 0o644) -> int:
    """``os.open`` that never follows a symbolic link at ``path`` (``O_NOFOLLOW``) and never
    writes into a file that was not made the way we make ours (:func:`_refuse_foreign`).

    Every file wmr opens for writing in a folder that may have come from someone else (a batch
    folder's journal, lock and worker logs, an FMU build folder's lock) goes through here.
    """
    path = Path(path)
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_CLOEXEC, mode)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise LogError(f"{path}: is a symbolic link; wmr never makes one: remove it, or "
                           f"write the {what} elsewhere") from None
        raise LogError(f"{path}: cannot create the {what}: {exc.strerror}") from exc
    try:
        _refuse_foreign(path, os.fstat(fd), what)
    except BaseException:
        os.close(fd)
        raise
    return fd


def _unique_temp(target: Path) -> tuple[int, Path]:
    """A new file beside ``target``, under a name nobody can have planted (``O_EXCL``), with
    the mode a new file gets (0666 less the umask, as ``open`` gives)."""
    for _ in range(100):
        tmp = target.with_name(f".{target.name}.{secrets.token_hex(8)}.tmp")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW
                         | os.O_CLOEXEC, 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise storage_error(exc, tmp) from exc
        return fd, tmp
    raise LogError(f"{target}: cannot find a free temporary name beside it")  # pragma: no cover


@contextmanager
def replacing(path: str | os.PathLike[str], durable: bool = False) -> Iterator[BinaryIO]:
    """Write a whole file and put it in place at once: a binary stream on a new temporary
    file beside ``path`` (:func:`_unique_temp`), renamed over ``path`` when the block ends,
    removed if it raises.  ``path`` itself is replaced, never written through: a symbolic
    link there is replaced, its target untouched.

    Parameters
    ----------
    path
        The final file.
    durable
        fsync the file and its folder, so that the rename survives a power loss.
    """
    target = Path(path)
    refuse_special(target)
    fd, tmp = _unique_temp(target)
    try:
        with open(fd, "wb") as stream:
            yield stream
            stream.flush()
            if durable:
                os.fsync(stream.fileno())
        refuse_special(target)
        os.replace(tmp, target)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise storage_error(exc, target) from exc  # the file asked for, not our temporary
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        fsync_dir(target.parent)


@contextmanager
def replacing_path(path: str | os.PathLike[str]) -> Iterator[str]:
    """:func:`replacing` for a library that opens and writes the file itself (Rerun's
    ``save``): a path to give it, the write end of a pipe whose bytes a thread of ours writes,
    as they come, to a new temporary file beside ``path``, renamed over ``path`` when the
    block ends, removed if it raises.  Until then ``path`` is the previous file, byte for byte.

    The library must have closed the file when the block ends (Rerun: ``disconnect``, or
    ``save_blueprint`` returning): the thread writes until the pipe's end of file.

    Raises
    ------
    DiskFullError
        The disk filled (``ENOSPC``, ``EDQUOT``): one line naming the device and ``path``.
    OSError
        Any other write error.
    """
    target = Path(path)
    failed: list[Exception] = []
    try:
        with replacing(target) as stream:
            fd = stream.fileno()  # written below the stream's buffer, which stays empty

            def copy(read_fd: int) -> None:
                # Rerun 0.41's file writer hangs for ever when one of its writes fails: the
                # pipe is drained to its end whatever happens here, and our own write's error
                # kept for later
                while chunk := os.read(read_fd, 1 << 20):
                    if not failed:
                        try:
                            write_all(fd, chunk, target)
                        except Exception as exc:  # raised in the caller's thread
                            failed.append(exc)

            read_fd, write_fd = os.pipe()
            thread = threading.Thread(target=copy, args=(read_fd,), name="wmr-replacing-path",
                                      daemon=True)
            thread.start()
            try:
                yield f"/dev/fd/{write_fd}"
            finally:
                os.close(write_fd)  # the library's own descriptor is closed: end of file
                thread.join()
                os.close(read_fd)
            if failed:
                raise failed[0]
    except DiskFullError as exc:
        raise DiskFullError(f"{exc} (the previous file is kept)") from exc


class AtomicFile:
    """A binary output that appears at ``path`` only when complete.

    Writes go to ``path + ".partial"``, opened without truncation, locked (``flock``), then
    emptied: a second writer to the same ``path`` is refused while the first one lives, and
    cannot cut its file short.  :meth:`commit` makes the file durable and renames it into
    place; :meth:`abandon` (or a crash) leaves it as ``.partial``.

    Parameters
    ----------
    path
        The final file.
    what
        What the file is, for messages (``"log"``).
    buffer_bytes
        Write buffer, bytes; :meth:`flush` hands it to the OS.
    durable
        fsync the file (and its folder) at :meth:`commit`, so that the rename survives a power
        loss, not only a killed process.  Off where a later check redoes what a power loss
        would damage (a batch's resume checks every log).

    Raises
    ------
    LogError
        The file cannot be created, or another process is writing it.
    ConfigError
        ``path`` is a device, a FIFO, a socket or a folder
        (:func:`wmr.infra.outputs.refuse_special`), now or at :meth:`commit`.
    """

    def __init__(self, path: str | os.PathLike[str], what: str = "file",
                 buffer_bytes: int = 1 << 20, durable: bool = True) -> None:
        self.path = Path(path)
        refuse_special(self.path)  # a device or FIFO there would be renamed over at the end
        self.durable = durable
        self.partial = partial_path(self.path)
        self._what = what
        for _ in range(10):
            fd = open_own(self.partial, os.O_RDWR | os.O_CREAT, what)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise LogError(f"{self.path}: another process is writing this {what} "
                               f"({self.partial.name} is locked); wait for it or choose "
                               "another output") from None
            # The previous holder may have renamed this very file into place between our
            # open and our lock: then it is a finished file, not ours to empty.  Retry.
            st = os.fstat(fd)
            try:
                same = os.path.samestat(st, os.stat(self.partial))
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        else:  # pragma: no cover - ten finished writers in a row
            raise LogError(f"{self.path}: the {what} keeps being replaced by another process")
        # emptied only when it holds something (a killed writer's prefix): on ext4, a
        # truncation to zero marks the file for its blocks to be allocated and written back
        # at its close, in the closing process (auto_da_alloc: 65 us of kernel CPU at the
        # close of a 650 kB log; a batch writes one per run), where a new file's are left
        # to the kernel's flusher
        if st.st_size:
            try:
                os.ftruncate(fd, 0)
            except OSError as exc:
                os.close(fd)
                raise storage_error(exc, self.partial) from exc
        self._fd = fd
        self._unsynced = 0  # bytes flushed or buffered since the last writeback started
        # C buffered writer: continues short writes itself; its OSError is mapped below
        self._file = open(fd, "wb", buffering=buffer_bytes, closefd=False)
        self.closed = False

    def write(self, data: bytes) -> int:
        """Buffer ``data`` (written out when the buffer is full)."""
        try:
            written = self._file.write(data)
        except OSError as exc:
            raise storage_error(exc, self.partial) from exc
        self._unsynced += written
        return written

    def flush(self) -> None:
        """Hand the buffered bytes to the OS (a killed process keeps them)."""
        try:
            self._file.flush()
        except OSError as exc:
            raise storage_error(exc, self.partial) from exc
        if self.durable and _start_writeback is not None and self._unsynced >= WRITEBACK_BYTES:
            self._unsynced = 0
            _start_writeback(self._fd)

    def seek(self, offset: int) -> int:
        """Move to byte ``offset`` (what is buffered is written out first)."""
        try:
            return self._file.seek(offset)
        except OSError as exc:
            raise storage_error(exc, self.partial) from exc

    def truncate(self) -> int:
        """Cut the file at the current position: the bytes after it are gone."""
        try:
            return self._file.truncate()
        except OSError as exc:
            raise storage_error(exc, self.partial) from exc

    def commit(self) -> None:
        """Write out, fsync, rename ``.partial`` over the final path, fsync the folder."""
        if self.closed:
            raise LogError(f"{self.path}: {self._what} committed after close")
        try:
            self.flush()
            if self.durable:
                try:
                    os.fsync(self._fd)
                except OSError as exc:
                    raise storage_error(exc, self.partial) from exc
            refuse_special(self.path)  # a FIFO made meanwhile: the log stays in .partial
            os.replace(self.partial, self.path)  # still locked: nobody can reopen it meanwhile
        finally:
            self.abandon()
        if self.durable:
            fsync_dir(self.path.parent)

    def abandon(self) -> None:
        """Stop writing; what was flushed stays in ``.partial``.  Idempotent."""
        if not self.closed:
            self.closed = True
            try:
                self._file.close()  # writes what is buffered, if it can
            except OSError:  # a full disk: what was flushed before stays
                pass
            os.close(self._fd)  # releases the lock

    close = abandon


__all__ = ["PARTIAL_SUFFIX", "AtomicFile", "fsync_dir", "mount_point", "open_own",
           "partial_path", "replacing", "storage_error", "write_all"]

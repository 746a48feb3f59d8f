"""One co-simulation FMU instance (FMI 2.0 or 3.0) through fmpy: what the robot plant
(:mod:`wmr.adapters.fmi.robot`) and the controller FMU (:mod:`wmr.adapters.fmi.controller`) share.

:class:`FmuSlave` extracts the FMU through the archive door
(:func:`wmr.adapters.fmi.archive.safe_extract`) into ``$TMPDIR/wmr-fmu-*``, a folder whose owner
file stays locked while the instance lives (:func:`remove_stale_folders` removes those of killed
processes); reads the model description; instantiates ``FMU2Slave`` or ``FMU3Slave`` with the
FMU's log messages on stderr (stdout is for results, ``--json``); binds the three calls of a step
(set the Float64 inputs, doStep, get the Float64 outputs) straight to the library with the
owner's prebuilt ctypes arrays; names statuses from one table; refuses every call after a Fatal
status (FMI 2.0, 2.1.3; FMI 3.0 likewise); and holds every difference between the FMI versions
(``setupExperiment``, ``setReal``/``setFloat64``, the FMU-state calls, ``doStep``'s arguments).
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import shutil
import stat
import sys
import tempfile
import threading
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, Final

from wmr.adapters.fmi.archive import check_model_identifier, safe_extract
from wmr.infra.errors import FmuError

#: Prefix of the folders an FMU is extracted to (in the temp folder).
TMP_PREFIX: Final = "wmr-fmu-"
#: File in such a folder, locked while its :class:`FmuSlave` lives.
_LOCK_NAME: Final = ".wmr-owner.lock"

#: fmi2Status and fmi3Status by value (``Pending``: FMI 2.0's asynchronous doStep only).
STATUS_NAMES: Final = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")
#: fmi2Warning and fmi3Warning: the last status a call may return and still have worked.
WARNING: Final = 1
#: fmi2Fatal and fmi3Fatal.
FATAL: Final = 4


def status_name(status: int) -> str:
    """The FMI name of a status value (the number itself when FMI has none)."""
    return STATUS_NAMES[status] if 0 <= status < len(STATUS_NAMES) else str(status)


def _hold(folder: Path) -> int | None:
    """Lock ``folder``'s owner file; the lock dies with the process, however it ends."""
    # locked under another name, then renamed: a cleaner never sees it unlocked
    tmp = folder / (_LOCK_NAME + ".new")
    try:
        fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
    except OSError:
        return None
    fcntl.flock(fd, fcntl.LOCK_EX)
    os.replace(tmp, folder / _LOCK_NAME)
    return fd


def remove_stale_folders(tmp_dir: str | Path | None = None) -> list[Path]:
    """Remove the extraction folders of FMU instances whose process is gone (killed runs).

    A folder counts as stale when it is ours (a folder, not a link, owned by this user), its
    owner file is a regular file of ours, and nobody holds its lock: folders without one
    (being created) or not ours are left alone.  The owner file is opened without following
    a link and read-only (``flock`` needs no more): another user's planted link cannot make
    this process open, lock or remove anything of theirs or of root's.  Returns the folders
    removed.
    """
    removed: list[Path] = []
    base = Path(tmp_dir) if tmp_dir is not None else Path(tempfile.gettempdir())
    uid = os.geteuid()
    flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    with contextlib.suppress(OSError):
        for folder in base.glob(TMP_PREFIX + "*"):
            try:
                dir_fd = os.open(folder, flags | os.O_DIRECTORY)
            except OSError:  # a link, or not a folder
                continue
            try:
                if os.fstat(dir_fd).st_uid != uid:
                    continue
                fd = os.open(_LOCK_NAME, flags, dir_fd=dir_fd)
            except OSError:  # a link, nothing there, or not ours to open
                continue
            finally:
                os.close(dir_fd)
            try:
                st = os.fstat(fd)
                if not stat.S_ISREG(st.st_mode) or st.st_uid != uid:
                    continue
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:  # its owner is alive
                continue
            else:
                shutil.rmtree(folder, ignore_errors=True)
                removed.append(folder)
            finally:
                os.close(fd)
    return removed


def checked_library(folder: Path, md: Any, where: str) -> Path:
    """The co-simulation library of the FMU extracted in ``folder`` (model description
    ``md``), where fmpy loads it from, once checked: its ``modelIdentifier`` a C identifier
    (:func:`wmr.adapters.fmi.archive.check_model_identifier`), and ``binaries``, the platform's
    folder and the library itself real folders and a regular file inside ``folder``, no link.

    Raises
    ------
    FmuError
        One line naming ``where`` (the FMU) and what is wrong; nothing has been loaded.
    """
    import fmpy

    identifier = check_model_identifier(md.coSimulation.modelIdentifier, where)
    # fmpy's own choice of folder: FMI 2 names platforms "linux64", FMI 3 "x86_64-linux"
    platform = fmpy.platform if md.fmiVersion.startswith("2") else fmpy.platform_tuple
    relative = Path("binaries", platform, identifier + fmpy.sharedLibraryExtension)
    at = folder
    for part in relative.parts:
        at = at / part
        try:
            st = os.lstat(at)
        except OSError:
            raise FmuError(f"{where}: has no binary for this platform ({relative.as_posix()} "
                           "is missing)") from None
        if stat.S_ISLNK(st.st_mode):
            raise FmuError(f"{where}: {at.relative_to(folder).as_posix()} is a symbolic link: "
                           "refused")
    if not stat.S_ISREG(st.st_mode):
        raise FmuError(f"{where}: {relative.as_posix()} is not a regular file: refused")
    return at


def _log(status: int, message: bytes | None) -> None:
    """An FMU's log message, on stderr: stdout is for results (``--json``), never for FMUs."""
    text = (message or b"").decode("utf-8", "replace")
    print(f"[{status_name(status).upper()}] {text}", file=sys.stderr)


def _fmi3_log(env: object, status: int, category: bytes, message: bytes) -> None:
    _log(status, message)


def _fmi2_log(component: object, instance: bytes, status: int, category: bytes,
              message: bytes) -> None:
    _log(status, message)


_FMI2_CALLBACKS: list[Any] = []

#: One model description read at a time in a process: fmpy validates it with a new lxml
#: ``XMLSchema`` each time, and libxml2 parsing schemas in two threads at once can break its
#: table of built-in types for the rest of the process (every later FMU then "unreadable
#: model description: ... xmlSchemaPValAttrNodeValue, the given type is not a built-in
#: type"): seen on a fresh two-thread Dask worker, all its runs failed.
_READ_MD = threading.Lock()


def fmi2_callbacks(log: Callable[..., None], *, format_messages: bool = False) -> Any:
    """fmpy's default FMI 2 callbacks (its ``calloc`` and ``free``) with ``log`` as the logger.

    ``log`` gets ``(component, instance, status, category, message)``.  The caller keeps the
    result alive while any instance made with it lives.  ``format_messages`` formats the
    variadic message in C through fmpy's logger proxy, which is one for the whole process:
    only the process-wide callbacks of :func:`_fmi2_callbacks` use it.
    """
    from fmpy import calloc, free
    from fmpy.fmi2 import (
        fmi2CallbackAllocateMemoryTYPE,
        fmi2CallbackFreeMemoryTYPE,
        fmi2CallbackFunctions,
        fmi2CallbackLoggerTYPE,
    )

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(log)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    if format_messages:
        try:
            from ctypes import byref

            from fmpy.logging import addLoggerProxy

            addLoggerProxy(byref(cb))
        except Exception:  # no proxy: messages arrive unformatted, still logged
            pass
    return cb


def _fmi2_callbacks() -> Any:
    """The FMI 2 callbacks of every :class:`FmuSlave`: the logger on stderr, messages
    formatted (one set per process)."""
    if not _FMI2_CALLBACKS:
        _FMI2_CALLBACKS.append(fmi2_callbacks(_fmi2_log, format_messages=True))
    return _FMI2_CALLBACKS[0]


class FmuSlave:
    """One co-simulation instance of an FMU (FMI 2.0 or 3.0), extracted, read and locked.

    Parameters
    ----------
    fmu_path
        The ``.fmu`` file.
    instance_name
        Name given to the instance (shows in its log messages).
    label
        Prefix of this instance's error messages (e.g. ``"controller FMU: "``).

    Raises
    ------
    FmuError
        The archive or its model description is unreadable.

    Notes
    -----
    The instance is made by the first :meth:`instantiate_or_reset`, and the owner then hands
    its arrays to :meth:`bind`.  The bound calls :attr:`raw_set`, :attr:`raw_step` and
    :attr:`raw_get` return the FMU's status; the owner turns a status above Warning into
    :meth:`status_error`.
    """

    def __init__(self, fmu_path: str | Path, instance_name: str, label: str = "") -> None:
        from fmpy import read_model_description

        self.fmu_path = Path(fmu_path)
        self._instance_name = instance_name
        self._label = label
        remove_stale_folders()
        self._tmp = Path(tempfile.mkdtemp(prefix=TMP_PREFIX))
        self._tmp_lock = _hold(self._tmp)
        try:
            safe_extract(self.fmu_path, self._tmp)
            with _READ_MD:
                md = read_model_description(str(self._tmp))
            # the bytes a log attaches: those of the instance this slave runs (extracted and
            # checked above), not the archive read again, which may have changed since
            xml = (self._tmp / "modelDescription.xml").read_bytes()
        except FmuError:
            self.remove_folder()
            raise
        except KeyError as exc:  # fmpy looks references up in a dict of the variables
            self.remove_folder()
            raise FmuError(f"{self.fmu_path}: invalid model description: value reference "
                           f"{exc.args[0] if exc.args else '?'} is used (in ModelStructure, a "
                           "derivative, dimension or clock) but no variable has it") from exc
        except Exception as exc:
            self.remove_folder()
            raise FmuError(f"{self.fmu_path}: unreadable model description: {exc}") from exc
        self.model_description: Any = md
        #: ``modelDescription.xml`` as extracted (what a run's log attaches).
        self.model_description_xml: bytes = xml
        self.fmi_version: str = md.fmiVersion
        self._fmi2 = self.fmi_version.startswith("2")
        #: fmpy's ``FMU2Slave``/``FMU3Slave`` once :meth:`instantiate_or_reset` made it.
        self.fmu: Any = None
        #: The FMU returned Fatal: FMI 2.0 (2.1.3) and 3.0 allow no further call to any of its
        #: instances, not even Terminate or FreeInstance.
        self.fatal = False
        #: The FMU's names of the three bound calls (set, doStep, get).
        self.names = (("fmi2SetReal", "fmi2DoStep", "fmi2GetReal") if self._fmi2
                      else ("fmi3SetFloat64", "fmi3DoStep", "fmi3GetFloat64"))
        self.raw_set: Callable[[], int] = self._unbound
        self.raw_get: Callable[[], int] = self._unbound
        self.raw_step: Callable[[float, float], int] = self._unbound

    @staticmethod
    def _unbound(*args: Any) -> int:
        raise RuntimeError("FmuSlave.bind was not called")

    # -- life cycle --------------------------------------------------------------------------

    def _instantiate(self) -> None:
        md = self.model_description
        library = checked_library(self._tmp, md, str(self.fmu_path))
        try:
            if self._fmi2:
                from fmpy.fmi2 import FMU2Slave

                fmu: Any = FMU2Slave(guid=md.guid, unzipDirectory=str(self._tmp),
                                     modelIdentifier=md.coSimulation.modelIdentifier,
                                     instanceName=self._instance_name,
                                     libraryPath=str(library))
                fmu.instantiate(loggingOn=False, callbacks=_fmi2_callbacks())
            else:
                from fmpy.fmi3 import FMU3Slave

                fmu = FMU3Slave(guid=md.guid, unzipDirectory=str(self._tmp),
                                modelIdentifier=md.coSimulation.modelIdentifier,
                                instanceName=self._instance_name)
                fmu.instantiate(loggingOn=False, logMessage=_fmi3_log)
        except Exception as exc:
            raise FmuError(f"{self.fmu_path}: cannot instantiate: {exc}") from exc
        self.fmu = fmu

    def instantiate_or_reset(self, at_s: float | None = None) -> bool:
        """Instantiate the FMU the first time, reset it after; whether it was made now (the
        owner then hands its arrays to :meth:`bind`).  ``at_s``: the time a failed reset
        names."""
        self.usable()
        if self.fmu is None:
            self._instantiate()
            return True
        self.call("reset", self.fmu.reset, at_s=at_s)
        return False

    def enter_initialization(self, at_s: float | None = None) -> None:
        """Start the experiment at t = 0 (FMI 2: ``setupExperiment``) and enter
        initialization mode.  ``at_s``: the time a failure names."""
        if self._fmi2:
            self.call("setupExperiment", self.fmu.setupExperiment, None, 0.0, at_s=at_s)
        self.call("enterInitializationMode", self.fmu.enterInitializationMode, at_s=at_s)

    def exit_initialization(self, at_s: float | None = None) -> None:
        """Leave initialization mode.  ``at_s``: the time a failure names."""
        self.call("exitInitializationMode", self.fmu.exitInitializationMode, at_s=at_s)

    def bind(self, in_vr: Any, in_val: Any, out_vr: Any, out_val: Any) -> None:
        """Bind the three calls of a step to the instance and the owner's ctypes arrays.

        fmpy's wrappers cost about as much again as the FMU's own step; the bound calls go
        to the library directly (fmpy set the prototypes) and return the status.
        """
        dll, comp = self.fmu.dll, self.fmu.component
        n_in, n_out = len(in_vr), len(out_vr)
        if self._fmi2:
            self.raw_set = partial(dll.fmi2SetReal, comp, in_vr, n_in, in_val)
            self.raw_get = partial(dll.fmi2GetReal, comp, out_vr, n_out, out_val)
            raw_step = dll.fmi2DoStep
            self.raw_step = lambda t, h: raw_step(comp, t, h, 1)
        else:
            self.raw_set = partial(dll.fmi3SetFloat64, comp, in_vr, n_in, in_val, n_in)
            self.raw_get = partial(dll.fmi3GetFloat64, comp, out_vr, n_out, out_val, n_out)
            # eventHandlingNeeded, terminateSimulation, earlyReturn, lastSuccessfulTime
            self._fmi3_out = (ctypes.c_bool(), ctypes.c_bool(), ctypes.c_bool(),
                              ctypes.c_double())
            refs = [ctypes.byref(f) for f in self._fmi3_out]
            raw_step3 = dll.fmi3DoStep
            self.raw_step = lambda t, h: raw_step3(comp, t, h, 1, *refs)

    def close(self) -> None:
        """Terminate and free the instance and remove the extraction folder (idempotent).

        After a Fatal status nothing is called (FMI 2.0, 2.1.3: "it is not possible to call
        any other function for any of the FMU instances"; FMI 3.0 likewise): the instance
        and its library are left as they are, a small leak where a call could crash the
        process (a foreign FMU's fmi2Terminate after fmi2Fatal did, SIGSEGV).
        """
        if self.fatal:
            self.fmu = None  # fmpy frees nothing by itself: the library stays loaded
        if self.fmu is not None:
            for fun in (self.fmu.terminate, self.fmu.freeInstance):
                try:
                    fun()
                except Exception:  # a failed run may leave the FMU in its error state
                    pass
            self.fmu = None
        self.remove_folder()

    def remove_folder(self) -> None:
        """Remove the extraction folder and release its lock (idempotent)."""
        shutil.rmtree(self._tmp, ignore_errors=True)
        if self._tmp_lock is not None:
            os.close(self._tmp_lock)
            self._tmp_lock = None

    # -- statuses and errors -----------------------------------------------------------------

    def status_error(self, which: int, status: int, at_s: float, inputs: str) -> FmuError:
        """The error of a status above Warning of bound call ``which`` (0 set, 1 step, 2 get)
        at ``at_s`` with the ``inputs`` (text) it had; a Fatal one also marks the FMU."""
        if status == FATAL:
            self.mark_fatal()
        return FmuError(f"{self._label}{self.names[which]} returned {status_name(status)} at "
                        f"t = {at_s:g} s ({inputs}); the FMU's log says why")

    def call(self, what: str, fun: Any, *args: Any, at_s: float | None = None) -> Any:
        """``fun(*args)``, one of fmpy's wrappers; a failure is an :class:`FmuError` naming
        ``what`` (and ``at_s``, when given)."""
        self.usable()
        try:
            return fun(*args)
        except Exception as exc:
            if getattr(exc, "status", None) == FATAL:  # fmpy's FMICallException
                self.mark_fatal()
            at = "" if at_s is None else f" at t = {at_s:g} s"
            raise FmuError(f"{self._label}{what} failed{at}: {exc}") from exc

    def mark_fatal(self) -> None:
        """The FMU returned Fatal: the bound calls now refuse instead of calling it (the
        check costs the hot path nothing)."""
        self.fatal = True

        def refuse(*args: Any) -> int:
            self.usable()
            return FATAL

        self.raw_set = self.raw_get = refuse
        self.raw_step = refuse

    def usable(self) -> None:
        """Refuse any call into an FMU that returned Fatal (the standard allows none)."""
        if self.fatal:
            raise FmuError(f"{self._label}{self.fmu_path.name} returned Fatal earlier: FMI "
                           "allows no further call to it; open the FMU again")

    # -- the calls whose names differ between FMI 2 and 3 -----------------------------------

    def set_float64(self, what: str, vrs: list[int], values: list[float],
                    at_s: float | None = None) -> None:
        """Set Float64 (FMI 2: Real) variables by value reference."""
        self.call(what, self.fmu.setReal if self._fmi2 else self.fmu.setFloat64, vrs, values,
                  at_s=at_s)

    def get_fmu_state(self, at_s: float | None = None) -> Any:
        """FMI get FMU state."""
        fmu = self.fmu
        return self.call("getFMUState", fmu.getFMUstate if self._fmi2 else fmu.getFMUState,
                         at_s=at_s)

    def set_fmu_state(self, state: Any, at_s: float | None = None) -> None:
        """FMI set FMU state."""
        fmu = self.fmu
        self.call("setFMUState", fmu.setFMUstate if self._fmi2 else fmu.setFMUState, state,
                  at_s=at_s)

    def serialize_fmu_state(self, state: Any, at_s: float | None = None) -> bytes:
        """FMI serialize FMU state."""
        fmu = self.fmu
        return bytes(self.call("serializeFMUState", fmu.serializeFMUstate if self._fmi2
                               else fmu.serializeFMUState, state, at_s=at_s))

    def deserialize_fmu_state(self, blob: bytes, at_s: float | None = None) -> Any:
        """FMI deserialize FMU state."""
        fmu = self.fmu
        return self.call("deserializeFMUState", fmu.deSerializeFMUstate if self._fmi2
                         else fmu.deserializeFMUState, blob, at_s=at_s)


__all__ = ["FATAL", "STATUS_NAMES", "TMP_PREFIX", "WARNING", "FmuSlave", "checked_library",
           "fmi2_callbacks", "remove_stale_folders", "status_name"]

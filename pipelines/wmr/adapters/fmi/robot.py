"""The FMU as a :class:`wmr.core.plant.Plant`: one instance, reset per run, fast per step.

Every FMI call goes through fmpy's wrappers, which raise ``fmpy.fmi1.FMICallException`` on an
error status; :class:`FmuPlant` turns those into :class:`wmr.infra.errors.FmuError` naming the
function.  The per-step path holds prebuilt ctypes arrays for the value references, the inputs
and the outputs, so a step allocates nothing and looks nothing up.

A robot FMU made by another tool is driven through a variable map
(:mod:`wmr.adapters.fmi.varmap`): the value references are the FMU's, and the inputs, outputs and
parameters pass through ``ours = scale * theirs + offset`` on the way.  Without a map (or with
one whose outputs all keep their unit) the outputs are the ctypes array itself.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import shutil
import sys
import tempfile
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wmr.adapters.fmi.archive import file_sha256, safe_extract
from wmr.adapters.fmi.varmap import VariableMap, resolve
from wmr.core.closedloop import LoopState
from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams
from wmr.infra.errors import ConfigError, FmuError


class FmuCall(ctypes.Structure):
    """One FMU instance and its exchange arrays, as the C stepper sees it (``wmr_fmu``)."""

    _fields_ = [("fmi_version", ctypes.c_int), ("n_in", ctypes.c_int),
                ("n_out", ctypes.c_int), ("pad", ctypes.c_int),
                ("instance", ctypes.c_void_p), ("set", ctypes.c_void_p),
                ("do_step", ctypes.c_void_p), ("get", ctypes.c_void_p),
                ("in_vr", ctypes.c_void_p), ("out_vr", ctypes.c_void_p),
                ("in_val", ctypes.c_void_p), ("out_val", ctypes.c_void_p),
                ("in_gain", ctypes.c_double * 2), ("in_bias", ctypes.c_double * 2)]


_STEPPER: list[Any] = []


def load_stepper() -> Any:
    """The C stepper library (ctypes), built on first use; None when it cannot be had.

    It also holds the MCAP row encoder of :class:`wmr.adapters.mcap.RunLogWriter`.

    ``WMR_STEPPER=0`` in the environment turns it off (the pure-Python path, same results).
    """
    if os.environ.get("WMR_STEPPER", "1") == "0":
        return None
    if not _STEPPER:
        lib: Any = None
        try:
            from wmr.build.fmus import build_stepper

            path = build_stepper()
            if path is not None:
                lib = ctypes.CDLL(str(path))
                ptr = ctypes.POINTER
                lib.wmr_exchange.argtypes = [ptr(FmuCall), ctypes.c_double, ctypes.c_double,
                                             ctypes.c_double, ctypes.c_double]
                lib.wmr_servo_step.argtypes = [ptr(FmuCall), ptr(LoopState), ctypes.c_double,
                                               ctypes.c_double, ctypes.c_int]
                lib.wmr_fmu_loop.argtypes = [ptr(FmuCall), ptr(FmuCall), ptr(LoopState)]
                for fun in (lib.wmr_exchange, lib.wmr_servo_step, lib.wmr_fmu_loop):
                    fun.restype = ctypes.c_int
                lib.wmr_encode_rows.argtypes = [ctypes.c_int, *[ctypes.c_void_p] * 2,
                                                *[ctypes.c_int] * 2, *[ctypes.c_void_p] * 8]
                lib.wmr_encode_rows.restype = ctypes.c_longlong
        except (OSError, AttributeError):  # no library, or an old one: the Python path
            lib = None
        _STEPPER.append(lib)
    return _STEPPER[0]


def fmu_call(fmi_version: str, dll: Any, component: Any, names: tuple[str, str, str],
             in_vr: Any, in_val: Any, out_vr: Any, out_val: Any) -> FmuCall:
    """The stepper's view of an instance: the FMU's own ``set``, ``doStep`` and ``get``."""
    call = FmuCall()
    call.fmi_version = 2 if fmi_version.startswith("2") else 3
    call.n_in, call.n_out = len(in_vr), len(out_vr)
    call.instance = component
    call.set, call.do_step, call.get = (ctypes.cast(getattr(dll, n), ctypes.c_void_p).value
                                        for n in names)
    call.in_vr, call.in_val = ctypes.addressof(in_vr), ctypes.addressof(in_val)
    call.out_vr, call.out_val = ctypes.addressof(out_vr), ctypes.addressof(out_val)
    call.in_gain[0] = call.in_gain[1] = 1.0
    return call


#: Prefix of the folders an FMU is extracted to (in the temp folder).
TMP_PREFIX = "wmr-fmu-"
#: File in such a folder, locked while its :class:`FmuPlant` lives.
_LOCK_NAME = ".wmr-owner.lock"


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


_LABELS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")
#: fmi2Fatal and fmi3Fatal.
_FATAL = 4


def _log(status: int, message: bytes | None) -> None:
    """An FMU's log message, on stderr: stdout is for results (``--json``), never for FMUs."""
    label = _LABELS[status] if 0 <= status < len(_LABELS) else str(status)
    text = (message or b"").decode("utf-8", "replace")
    print(f"[{label}] {text}", file=sys.stderr)


def _fmi3_log(env: object, status: int, category: bytes, message: bytes) -> None:
    _log(status, message)


def _fmi2_log(component: object, instance: bytes, status: int, category: bytes,
              message: bytes) -> None:
    _log(status, message)


_FMI2_CALLBACKS: list[Any] = []


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
    """The FMI 2 callbacks of every :class:`FmuPlant`: the logger on stderr, messages
    formatted (one set per process)."""
    if not _FMI2_CALLBACKS:
        _FMI2_CALLBACKS.append(fmi2_callbacks(_fmi2_log, format_messages=True))
    return _FMI2_CALLBACKS[0]


def remove_stale_folders(tmp_dir: str | Path | None = None) -> list[Path]:
    """Remove the extraction folders of FMU plants whose process is gone (killed runs).

    A folder counts as stale when its owner file exists and nobody holds its lock: folders
    without one (being created, or not ours) are left alone.  Returns the folders removed.
    """
    removed: list[Path] = []
    base = Path(tmp_dir) if tmp_dir is not None else Path(tempfile.gettempdir())
    with contextlib.suppress(OSError):
        for folder in base.glob(TMP_PREFIX + "*"):
            try:
                fd = os.open(folder / _LOCK_NAME, os.O_RDWR | os.O_CLOEXEC)
            except OSError:
                continue
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:  # its owner is alive
                os.close(fd)
                continue
            shutil.rmtree(folder, ignore_errors=True)
            os.close(fd)
            removed.append(folder)
    return removed


class FmuPlant:
    """Drive a co-simulation FMU of the robot (FMI 2.0 or 3.0) through fmpy.

    Parameters
    ----------
    fmu_path
        The ``.fmu`` file.
    instance_name
        Name given to the FMU instance (shows in its log messages).
    var_map
        How our interface names map to the FMU's variables (:mod:`wmr.adapters.fmi.varmap`);
        ``None``: the FMU has our names and units.
    """

    def __init__(self, fmu_path: str | Path, instance_name: str = "robot",
                 var_map: VariableMap | None = None) -> None:
        from fmpy import read_model_description

        self.fmu_path = Path(fmu_path)
        remove_stale_folders()
        self._tmp = Path(tempfile.mkdtemp(prefix=TMP_PREFIX))
        self._tmp_lock = _hold(self._tmp)
        try:
            safe_extract(self.fmu_path, self._tmp)
            md = read_model_description(str(self._tmp))
        except FmuError:
            self._drop_tmp()
            raise
        except KeyError as exc:  # fmpy looks references up in a dict of the variables
            self._drop_tmp()
            raise FmuError(f"{self.fmu_path}: invalid model description: value reference "
                           f"{exc.args[0] if exc.args else '?'} is used (in ModelStructure, a "
                           "derivative, dimension or clock) but no variable has it") from exc
        except Exception as exc:
            self._drop_tmp()
            raise FmuError(f"{self.fmu_path}: unreadable model description: {exc}") from exc
        if md.coSimulation is None:
            self._drop_tmp()
            raise FmuError(f"{self.fmu_path}: not a co-simulation FMU")
        self.model_description = md
        self.fmi_version = md.fmiVersion
        self.sha256 = file_sha256(self.fmu_path)
        try:
            self._map = resolve(var_map, md, self.fmu_path.name)
        except ConfigError:
            self._drop_tmp()
            raise
        self.var_map = var_map
        self._fmu: Any = None
        #: The FMU returned Fatal: FMI 2.0 (2.1.3) and 3.0 allow no further call to any of its
        #: instances, not even Terminate or FreeInstance.
        self._fatal = False
        self._t = self._t0 = self._h = 0.0
        self._n = 0
        self._instance_name = instance_name
        self._make_arrays()

    def _make_arrays(self) -> None:
        vr_type = ctypes.c_uint32
        rm = self._map
        self._in_vr = (vr_type * 2)(*(vr for vr, _ in rm.inputs))
        self._in_val = (ctypes.c_double * 2)()
        # theirs = ours * gain + bias for the two torques
        (_, e_r), (_, e_l) = rm.inputs
        self._in_names = (e_r.name, e_l.name)  # the FMU's names of tau_r and tau_l
        self._in_gain_r, self._in_bias_r = 1.0 / e_r.scale, -e_r.offset / e_r.scale
        self._in_gain_l, self._in_bias_l = 1.0 / e_l.scale, -e_l.offset / e_l.scale
        present = [(i, o) for i, o in enumerate(rm.outputs) if o is not None]
        self._n_out = len(present)
        self._out_vr = (vr_type * self._n_out)(*(o[0] for _, o in present))
        self._out_val = (ctypes.c_double * self._n_out)()
        raw: npt.NDArray[np.float64] = np.ctypeslib.as_array(self._out_val)
        self._raw_out = raw
        self._outputs: npt.NDArray[np.float64]
        if rm.identity:
            self._outputs = raw
            self._convert = False
        else:
            self._outputs = np.full(len(OUTPUT_NAMES), np.nan)
            self._out_idx = np.array([i for i, _ in present], dtype=np.intp)
            self._out_scale = np.array([o[1].scale for _, o in present])
            self._out_offset = np.array([o[1].offset for _, o in present])
            self._convert = True

    def _get_outputs(self) -> None:
        """Read the outputs into :attr:`_outputs`, in our names' order and units."""
        self._check(2, self._raw_get())
        if self._convert:
            self._outputs[self._out_idx] = self._raw_out * self._out_scale + self._out_offset

    def _instantiate(self) -> None:
        md = self.model_description
        try:
            if self.fmi_version.startswith("2"):
                from fmpy.fmi2 import FMU2Slave

                fmu: Any = FMU2Slave(guid=md.guid, unzipDirectory=str(self._tmp),
                                     modelIdentifier=md.coSimulation.modelIdentifier,
                                     instanceName=self._instance_name)
                fmu.instantiate(loggingOn=False, callbacks=_fmi2_callbacks())
            else:
                from fmpy.fmi3 import FMU3Slave

                fmu = FMU3Slave(guid=md.guid, unzipDirectory=str(self._tmp),
                                modelIdentifier=md.coSimulation.modelIdentifier,
                                instanceName=self._instance_name)
                fmu.instantiate(loggingOn=False, logMessage=_fmi3_log)
        except Exception as exc:
            raise FmuError(f"{self.fmu_path}: cannot instantiate: {exc}") from exc
        self._fmu = fmu
        self._bind_hot_path(fmu)

    def _bind_hot_path(self, fmu: Any) -> None:
        """The three calls of a step, bound once to the instance and the prebuilt arrays.

        fmpy's wrappers cost about as much again as the FMU's own step; the input and output
        exchange calls the library directly (fmpy set the prototypes) and :meth:`_check`
        turns a status above fmiWarning into an :class:`FmuError` naming the function.
        """
        dll, comp, n_out = fmu.dll, fmu.component, self._n_out
        if self.fmi_version.startswith("2"):
            self._names = ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal")
            self._raw_set = partial(dll.fmi2SetReal, comp, self._in_vr, 2, self._in_val)
            self._raw_get = partial(dll.fmi2GetReal, comp, self._out_vr, n_out, self._out_val)
            raw_step = dll.fmi2DoStep
            self._raw_step = lambda t, h: raw_step(comp, t, h, 1)
        else:
            self._names = ("fmi3SetFloat64", "fmi3DoStep", "fmi3GetFloat64")
            self._raw_set = partial(dll.fmi3SetFloat64, comp, self._in_vr, 2, self._in_val, 2)
            self._raw_get = partial(dll.fmi3GetFloat64, comp, self._out_vr, n_out,
                                    self._out_val, n_out)
            # eventHandlingNeeded, terminateSimulation, earlyReturn, lastSuccessfulTime
            self._fmi3_out = (ctypes.c_bool(), ctypes.c_bool(), ctypes.c_bool(), ctypes.c_double())
            flags = [ctypes.byref(f) for f in self._fmi3_out[:3]]
            last = ctypes.byref(self._fmi3_out[3])
            raw_step3 = dll.fmi3DoStep
            self._raw_step = lambda t, h: raw_step3(comp, t, h, 1, *flags, last)
        self._fast: Any = None
        lib = load_stepper()
        if lib is not None:
            call = fmu_call(self.fmi_version, dll, comp, self._names, self._in_vr,
                            self._in_val, self._out_vr, self._out_val)
            call.in_gain[0], call.in_bias[0] = self._in_gain_r, self._in_bias_r
            call.in_gain[1], call.in_bias[1] = self._in_gain_l, self._in_bias_l
            self.fmu_call = call
            self._call_ref = ctypes.byref(call)
            self._fast = partial(lib.wmr_exchange, self._call_ref)

    def _check(self, which: int, status: int) -> None:
        """Raise for a status above fmiWarning of call ``which`` (0 set, 1 step, 2 get)."""
        if status <= 1:
            return
        if status == _FATAL:
            self._mark_fatal()
        name = ("OK", "Warning", "Discard", "Error", "Fatal")[status] if status < 5 else status
        raise FmuError(f"{self._names[which]} returned {name} at t = {self._t:g} s "
                       f"({self._in_names[0]} = {self._in_val[0]!r}, "
                       f"{self._in_names[1]} = {self._in_val[1]!r}); "
                       "the FMU's log says why")

    def _call(self, what: str, fun: Any, *args: Any) -> Any:
        self._usable()
        try:
            return fun(*args)
        except Exception as exc:
            if getattr(exc, "status", None) == _FATAL:  # fmpy's FMICallException
                self._mark_fatal()
            raise FmuError(f"{what} failed at t = {self._t:g} s: {exc}") from exc

    def _mark_fatal(self) -> None:
        """The FMU returned Fatal: the step's bound calls now refuse instead of calling it
        (the check costs the hot path nothing)."""
        self._fatal = True

        def refuse(*args: Any) -> int:
            self._usable()
            return _FATAL

        self._raw_set = self._raw_get = partial(refuse)
        self._raw_step = refuse

    def _usable(self) -> None:
        """Refuse any call into an FMU that returned Fatal (the standard allows none)."""
        if self._fatal:
            raise FmuError(f"{self.fmu_path.name} returned Fatal earlier: FMI allows no "
                           "further call to it; open the FMU again")

    def reset(self, params: RobotParams, start: Pose, v0_mps: float = 0.0,
              omega0_radps: float = 0.0) -> npt.NDArray[np.float64]:
        """Start a run at t = 0 from ``start`` with ``params``; return the outputs at t = 0."""
        self._usable()
        if self._fmu is None:
            self._instantiate()
        else:
            self._call("reset", self._fmu.reset)
        fmu = self._fmu
        values = params.as_dict()
        values.update(x0=start.x_m, y0=start.y_m, theta0=start.heading_rad, v0=v0_mps,
                      omega0=omega0_radps)
        vrs, theirs = self._parameter_values(values)
        self._t, self._t0, self._h, self._n = 0.0, 0.0, 0.0, 0
        if self.fmi_version.startswith("2"):
            self._call("setupExperiment", fmu.setupExperiment, None, 0.0)
        self._call("enterInitializationMode", fmu.enterInitializationMode)
        try:
            if self.fmi_version.startswith("2"):
                fmu.setReal(vrs, theirs)
            else:
                fmu.setFloat64(vrs, theirs)
        except Exception as exc:
            if getattr(exc, "status", None) == _FATAL:  # fmpy's FMICallException
                self._mark_fatal()
            raise FmuError(f"setting the parameters {values} failed: {exc}") from exc
        self._in_val[0] = self._in_bias_r
        self._in_val[1] = self._in_bias_l
        self._check(0, self._raw_set())
        self._call("exitInitializationMode", fmu.exitInitializationMode)
        self._get_outputs()
        return self._outputs

    def _parameter_values(self, values: dict[str, float]) -> tuple[list[int], list[float]]:
        """Value references and the FMU's values of our parameters ``values`` (those it has).

        A parameter the map leaves unmapped keeps the FMU's own value.
        """
        params = self._map.parameters
        vrs = [params[n][0] for n in values if n in params]
        theirs = [params[n][1].to_theirs(v) for n, v in values.items() if n in params]
        return vrs, theirs

    def step(self, tau_r_nm: float, tau_l_nm: float, h_s: float) -> npt.NDArray[np.float64]:
        """Hold the torques for ``h_s`` seconds; the returned array is reused by the next step."""
        if self._fast is not None:  # the same three calls, made by the C stepper
            code = self._fast(tau_r_nm, tau_l_nm, self._t, h_s)
            if code:
                self.raise_step_error(code)
            if self._convert:
                self._outputs[self._out_idx] = (self._raw_out * self._out_scale
                                                + self._out_offset)
        else:
            self._in_val[0] = tau_r_nm * self._in_gain_r + self._in_bias_r
            self._in_val[1] = tau_l_nm * self._in_gain_l + self._in_bias_l
            # a failed call raises; the outputs keep their last good values
            self._check(0, self._raw_set())
            self._check(1, self._raw_step(self._t, h_s))
            self._get_outputs()
        # Time is t0 + n*h while h stays the same (never t += h): no drift over long runs.
        if h_s != self._h:
            self._t0, self._h, self._n = self._t, h_s, 0
        self._n += 1
        self._t = self._t0 + self._n * h_s
        return self._outputs

    def raise_step_error(self, code: int) -> None:
        """Raise the :class:`FmuError` of a stepper status ``16 * (call + 1) + status``."""
        self._check(code // 16 - 1, code % 16)

    def stepper(self) -> tuple[Any, FmuCall] | None:
        """The C stepper and this instance's view for it, when both are there and the outputs
        need no conversion (a mapped FMU with other units steps through :meth:`step`)."""
        if self._fast is None or self._convert:
            return None
        return load_stepper(), self.fmu_call

    def set_clock(self, h_s: float, n: int) -> None:
        """The clock after ``n`` steps of ``h_s`` from t = 0 taken by the stepper, as
        :meth:`step` would have left it."""
        self._t0, self._h, self._n = 0.0, h_s, n
        self._t = self._t0 + n * h_s

    @property
    def time_s(self) -> float:
        """The communication point the FMU is at."""
        return self._t

    def outputs(self) -> dict[str, float]:
        """The current outputs by FMU name."""
        return dict(zip(OUTPUT_NAMES, self._outputs.tolist(), strict=True))

    def set_parameters(self, **values: float) -> None:
        """Change tunable parameters (e.g. ``m`` for a load change) between steps."""
        unknown = [n for n in values if n not in self._map.parameters]
        if unknown:
            raise ConfigError(f"parameter {unknown[0]}", f"{self.fmu_path.name} has no "
                              "such parameter (or the map leaves it unmapped)",
                              "set one of: " + ", ".join(self._map.parameters))
        vrs, theirs = self._parameter_values(dict(values))
        setter = self._fmu.setReal if self.fmi_version.startswith("2") else self._fmu.setFloat64
        self._call(f"setting {values}", setter, vrs, theirs)

    def get_state(self) -> tuple[Any, float, float, float, int]:
        """Snapshot of the FMU state and of the master's clock (FMI get FMU state)."""
        fmu = self._fmu
        getter = fmu.getFMUstate if self.fmi_version.startswith("2") else fmu.getFMUState
        return (self._call("getFMUState", getter), self._t, self._t0, self._h, self._n)

    def set_state(self, snapshot: tuple[Any, float, float, float, int]) -> None:
        """Go back to a snapshot of :meth:`get_state`."""
        fmu = self._fmu
        setter = fmu.setFMUstate if self.fmi_version.startswith("2") else fmu.setFMUState
        self._call("setFMUState", setter, snapshot[0])
        self._t, self._t0, self._h, self._n = snapshot[1:]
        self._get_outputs()

    def serialize_state(self, snapshot: tuple[Any, float, float, float, int]) -> bytes:
        """Bytes of a snapshot's FMU state (FMI serialize FMU state)."""
        fmu = self._fmu
        ser = fmu.serializeFMUstate if self.fmi_version.startswith("2") else fmu.serializeFMUState
        return bytes(self._call("serializeFMUState", ser, snapshot[0]))

    def deserialize_state(self, blob: bytes, clock: tuple[float, float, float, int]
                          ) -> tuple[Any, float, float, float, int]:
        """A snapshot from bytes of :meth:`serialize_state` and the clock it was taken at."""
        fmu = self._fmu
        de = (fmu.deSerializeFMUstate if self.fmi_version.startswith("2")
              else fmu.deserializeFMUState)
        return (self._call("deserializeFMUState", de, blob), *clock)

    def close(self) -> None:
        """Terminate and free the instance and remove the extraction folder.

        After a Fatal status nothing is called (FMI 2.0, 2.1.3: "it is not possible to call
        any other function for any of the FMU instances"; FMI 3.0 likewise): the instance
        and its library are left as they are, a small leak where a call could crash the
        process (a foreign FMU's fmi2Terminate after fmi2Fatal did, SIGSEGV).
        """
        if self._fatal:
            self._fmu = None  # fmpy frees nothing by itself: the library stays loaded
        if self._fmu is not None:
            try:
                self._fmu.terminate()
            except Exception:  # a failed run may leave the FMU in its error state
                pass
            try:
                self._fmu.freeInstance()
            except Exception:  # same: nothing left to do but free it
                pass
            self._fmu = None
        self._drop_tmp()

    def _drop_tmp(self) -> None:
        """Remove the extraction folder (idempotent)."""
        shutil.rmtree(self._tmp, ignore_errors=True)
        if self._tmp_lock is not None:
            os.close(self._tmp_lock)
            self._tmp_lock = None

    def __enter__(self) -> FmuPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

"""The controller FMU as the master loop's controller (``wmr run --controller-fmu``).

:class:`FmuController` is a :class:`wmr.core.closedloop.Controller` (``configure``, ``step``,
and a ``stabiliser`` with ``converged`` and ``heading_error``), so the master drives the C
controller in place of the Python one. Per control step the master calls
``stabiliser.converged`` (set the pose and speeds, read the ``converged`` output: the test runs
on the state before the sample, as in Python) and then ``step`` (set all seven inputs, read the
outputs of the sample, then doStep over exactly one control period). As in
:class:`wmr.adapters.fmi.robot.FmuPlant` the per-step calls go straight to the shared library
through ctypes with prebuilt arrays.
"""

from __future__ import annotations

import ctypes
import math
import shutil
import tempfile
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from wmr.adapters.fmi.archive import file_sha256, safe_extract
from wmr.adapters.fmi.robot import FmuCall, fmu_call
from wmr.build.controller_interface import INPUTS, SIGNAL_OUTPUTS
from wmr.core.closedloop import LoopState
from wmr.core.control import wrap_angle
from wmr.core.runspec import RunSpec
from wmr.infra.errors import ConfigError, FmuError

_OUTPUTS = (*SIGNAL_OUTPUTS, "phase", "converged")
_N_SIG = len(SIGNAL_OUTPUTS)
_I_CONVERGED = _OUTPUTS.index("converged")
_STATUS = ("OK", "Warning", "Discard", "Error", "Fatal")


def controller_parameters(spec: RunSpec) -> dict[str, float]:
    """The controller FMU's parameters of a run, by FMU name (the scenario files' names)."""
    values = {"goal.x_m": spec.goal.x_m, "goal.y_m": spec.goal.y_m,
              "goal.heading_deg": math.degrees(spec.goal.heading_rad)}
    values |= {f"gains.{k}": v for k, v in spec.gains.as_dict().items()}
    values |= {f"limits.{k}": v for k, v in spec.limits.as_dict().items()}
    params = spec.params.as_dict()
    values |= {f"params.{k}": params[k] for k in ("r", "L", "b_f", "tau_c", "w_c")}
    values |= {"control_period_s": spec.period_s, "stop_radius_m": spec.stop_radius_m,
               "heading_tolerance_deg": math.degrees(spec.heading_tolerance_rad)}
    return values


class _Stabiliser:
    """The part of :class:`wmr.core.control.Stabiliser` the master loop calls, answered by the
    FMU."""

    __slots__ = ("_ctrl",)

    def __init__(self, ctrl: FmuController) -> None:
        self._ctrl = ctrl

    def converged(self, x: float, y: float, theta: float, v: float, omega: float,
                  heading_tolerance_rad: float) -> bool:
        """The FMU's ``converged`` output for this measurement.

        The FMU tests against its parameter ``heading_tolerance_deg`` (set from the run by
        :meth:`FmuController.configure`); another tolerance here is an error, not ignored.
        """
        ctrl = self._ctrl
        if abs(heading_tolerance_rad - ctrl.heading_tolerance_rad) > 1e-12:
            raise ConfigError("heading_tolerance_deg", f"the controller FMU was configured with "
                              f"{math.degrees(ctrl.heading_tolerance_rad):g} deg, asked with "
                              f"{math.degrees(heading_tolerance_rad):g} deg",
                              "configure the FMU with the run it drives")
        return ctrl._converged(x, y, theta, v, omega)

    def heading_error(self, theta: float) -> float:
        """Heading minus the desired heading, wrapped, rad."""
        return wrap_angle(theta - self._ctrl.goal_heading_rad)


class FmuController:
    """Drive the controller FMU (FMI 2.0 or 3.0) as a :class:`~wmr.core.control.ServoedController`.

    Parameters
    ----------
    fmu_path
        A ``wmr_controller-fmi*.fmu`` (or any FMU with its variable names).
    instance_name
        Name of the FMU instance in its log messages.

    Call :meth:`configure` with a run before the first :meth:`step`.
    """

    #: The C stepper runs whole blocks of the loop (:class:`wmr.core.closedloop.Controller`).
    stepper_kind = "blocks"

    def __init__(self, fmu_path: str | Path, instance_name: str = "controller") -> None:
        from fmpy import read_model_description

        self.fmu_path = Path(fmu_path)
        self._tmp = Path(tempfile.mkdtemp(prefix="wmr-ctrl-"))
        try:
            safe_extract(self.fmu_path, self._tmp)
            md = read_model_description(str(self._tmp))
        except FmuError:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        except Exception as exc:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise FmuError(f"{self.fmu_path}: unreadable model description: {exc}") from exc
        self.model_description = md
        self.fmi_version: str = md.fmiVersion
        self.sha256 = file_sha256(self.fmu_path)
        self._vr = {v.name: v.valueReference for v in md.modelVariables}
        causality = {v.name: v.causality for v in md.modelVariables}
        wrong = [f"{n} ({causality.get(n, 'missing')})" for n in INPUTS
                 if causality.get(n) != "input"]
        wrong += [f"{n} ({causality.get(n, 'missing')})" for n in _OUTPUTS
                  if causality.get(n) != "output"]
        if md.coSimulation is None or wrong:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise FmuError(f"{self.fmu_path}: not a controller FMU (a co-simulation FMU with "
                           f"the inputs {', '.join(INPUTS)} and the outputs tau_r, tau_l, ...); "
                           f"wrong: {', '.join(wrong[:6]) or 'no co-simulation'}"
                           + (f" and {len(wrong) - 6} more" if len(wrong) > 6 else ""))
        self._instance_name = instance_name
        self._fmu: Any = None
        self._t = 0.0
        self._n = 0
        self._h = 0.0
        self.goal_heading_rad = 0.0
        self.heading_tolerance_rad = math.nan
        self.stabiliser = _Stabiliser(self)
        vr_t = ctypes.c_uint32
        self._in_vr = (vr_t * len(INPUTS))(*(self._vr[n] for n in INPUTS))
        self._in_val = (ctypes.c_double * len(INPUTS))()
        self._out_vr = (vr_t * len(_OUTPUTS))(*(self._vr[n] for n in _OUTPUTS))
        self._out_val = (ctypes.c_double * len(_OUTPUTS))()
        self._outputs = np.ctypeslib.as_array(self._out_val)

    def _instantiate(self) -> None:
        md = self.model_description
        try:
            if self.fmi_version.startswith("2"):
                from fmpy.fmi2 import FMU2Slave as Slave
            else:
                from fmpy.fmi3 import FMU3Slave as Slave
            fmu: Any = Slave(guid=md.guid, unzipDirectory=str(self._tmp),
                             modelIdentifier=md.coSimulation.modelIdentifier,
                             instanceName=self._instance_name)
            fmu.instantiate(loggingOn=False)
        except Exception as exc:
            raise FmuError(f"{self.fmu_path}: cannot instantiate: {exc}") from exc
        self._fmu = fmu
        dll, comp, n_in, n_out = fmu.dll, fmu.component, len(INPUTS), len(_OUTPUTS)
        if self.fmi_version.startswith("2"):
            self._names = ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal")
            self._raw_set = partial(dll.fmi2SetReal, comp, self._in_vr, n_in, self._in_val)
            self._raw_get = partial(dll.fmi2GetReal, comp, self._out_vr, n_out, self._out_val)
            raw_step = dll.fmi2DoStep
            self._raw_step = lambda t, h: raw_step(comp, t, h, 1)
        else:
            self._names = ("fmi3SetFloat64", "fmi3DoStep", "fmi3GetFloat64")
            self._raw_set = partial(dll.fmi3SetFloat64, comp, self._in_vr, n_in, self._in_val,
                                    n_in)
            self._raw_get = partial(dll.fmi3GetFloat64, comp, self._out_vr, n_out,
                                    self._out_val, n_out)
            flags = (ctypes.c_bool(), ctypes.c_bool(), ctypes.c_bool(), ctypes.c_double())
            self._fmi3_flags = flags
            refs = [ctypes.byref(f) for f in flags]
            raw_step3 = dll.fmi3DoStep
            self._raw_step = lambda t, h: raw_step3(comp, t, h, 1, *refs)
        #: this instance as the C stepper sees it (``wmr_fmu_loop``)
        self.fmu_call = fmu_call(self.fmi_version, dll, comp, self._names, self._in_vr,
                                 self._in_val, self._out_vr, self._out_val)

    def _check(self, which: int, status: int) -> None:
        if status <= 1:
            return
        name = _STATUS[status] if status < len(_STATUS) else status
        inputs = ", ".join(f"{n} = {v!r}" for n, v in zip(INPUTS, self._in_val, strict=True))
        raise FmuError(f"controller FMU: {self._names[which]} returned {name} at "
                       f"t = {self._t:g} s ({inputs}); the FMU's log says why")

    def raise_step_error(self, code: int) -> None:
        """Raise the :class:`FmuError` of a stepper status ``16 * (call + 1) + status``."""
        self._check(code // 16 - 1, code % 16)

    def set_clock(self, n: int) -> None:
        """The clock after ``n`` samples taken by the stepper, as :meth:`step` leaves it."""
        self._n = n
        self._t = n * self._h

    def block_loop(self, lib: Any, plant_call: FmuCall, state: LoopState) -> Callable[[], int]:
        """The C call that runs both FMUs' closed loop until the block of ``state`` is full or
        the run ends (``wmr_fmu_loop``)."""
        state.i_converged = _I_CONVERGED
        return partial(lib.wmr_fmu_loop, ctypes.byref(plant_call), ctypes.byref(self.fmu_call),
                       ctypes.byref(state))

    def configure(self, spec: RunSpec) -> None:
        """Set the run's goal, gains, limits, robot and timing, and start at t = 0."""
        if spec.controller != "pi":
            raise ConfigError("controller_fmu", f"the controller FMU is the paper's PI "
                              f"stabiliser, but the run asks for controller = "
                              f"{spec.controller!r}", "drop controller_fmu or use pi")
        if self._fmu is None:
            self._instantiate()
        else:
            self._call("reset", self._fmu.reset)
        fmu = self._fmu
        values = controller_parameters(spec)
        unknown = [n for n in values if n not in self._vr]
        if unknown:
            raise FmuError(f"{self.fmu_path}: lacks the parameters {', '.join(unknown)}")
        self.goal_heading_rad = spec.goal.heading_rad
        self.heading_tolerance_rad = spec.heading_tolerance_rad
        self._t, self._n, self._h = 0.0, 0, spec.period_s
        if self.fmi_version.startswith("2"):
            self._call("setupExperiment", fmu.setupExperiment, None, 0.0)
        self._call("enterInitializationMode", fmu.enterInitializationMode)
        setter = fmu.setReal if self.fmi_version.startswith("2") else fmu.setFloat64
        self._call(f"setting the parameters {values}", setter,
                   [self._vr[n] for n in values], list(values.values()))
        self._call("exitInitializationMode", fmu.exitInitializationMode)

    def _call(self, what: str, fun: Any, *args: Any) -> Any:
        try:
            return fun(*args)
        except Exception as exc:
            raise FmuError(f"controller FMU: {what} failed: {exc}") from exc

    def reset(self) -> None:
        """Nothing to do: :meth:`configure` starts every run from the FMU's reset state."""

    def _converged(self, x: float, y: float, theta: float, v: float, omega: float) -> bool:
        val = self._in_val
        val[0], val[1], val[2], val[3], val[4] = x, y, theta, v, omega
        self._check(0, self._raw_set())
        self._check(2, self._raw_get())
        return bool(self._outputs[_I_CONVERGED] != 0.0)

    def step(self, x: float, y: float, theta: float, omega_r: float,
             omega_l: float) -> tuple[float, ...]:
        """One control period: the sample's :data:`~wmr.core.signals.CONTROL_SIGNALS`, then doStep.

        ``v`` and ``omega`` are those of the last ``stabiliser.converged`` call (they only
        enter the convergence test).
        """
        val = self._in_val
        val[0], val[1], val[2], val[5], val[6] = x, y, theta, omega_r, omega_l
        self._check(0, self._raw_set())
        self._check(2, self._raw_get())
        sig = tuple(self._outputs[:_N_SIG].tolist())
        self._check(1, self._raw_step(self._t, self._h))
        self._n += 1
        self._t = self._n * self._h  # t_n = n h, never accumulated
        return sig

    def close(self) -> None:
        if self._fmu is not None:
            for fun in (self._fmu.terminate, self._fmu.freeInstance):
                try:
                    fun()
                except Exception:  # a failed run may leave the FMU in its error state
                    pass
            self._fmu = None
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> FmuController:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["FmuController", "controller_parameters"]

"""The controller FMU as the master loop's controller (``wmr run --controller-fmu``).

:class:`FmuController` is a :class:`wmr.core.closedloop.Controller` (``configure``, ``step``,
and a ``stabiliser`` with ``converged`` and ``heading_error``), so the master drives the C
controller in place of the Python one. Per control step the master calls
``stabiliser.converged`` (set the pose and speeds, read the ``converged`` output: the test runs
on the state before the sample, as in Python) and then ``step`` (set all seven inputs, read the
outputs of the sample, then doStep over exactly one control period). The instance (extraction,
FMI 2 or 3, statuses, the per-step calls bound to prebuilt ctypes arrays) is a
:class:`wmr.adapters.fmi.slave.FmuSlave`, as the robot's in
:class:`wmr.adapters.fmi.robot.FmuPlant` is.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from wmr.adapters.fmi.archive import file_sha256
from wmr.adapters.fmi.robot import fmu_call
from wmr.adapters.fmi.slave import WARNING, FmuSlave
from wmr.adapters.stepper import FmuCall, LoopState
from wmr.build.controller_interface import INPUTS, SIGNAL_OUTPUTS
from wmr.core.control import wrap_angle
from wmr.core.runspec import RunSpec
from wmr.infra.errors import ConfigError, FmuError

_OUTPUTS = (*SIGNAL_OUTPUTS, "phase", "converged")
_N_SIG = len(SIGNAL_OUTPUTS)
_I_CONVERGED = _OUTPUTS.index("converged")


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
        self.fmu_path = Path(fmu_path)
        self._slave = slave = FmuSlave(self.fmu_path, instance_name, label="controller FMU: ")
        md = slave.model_description
        self.model_description = md
        self.fmi_version: str = slave.fmi_version
        self.sha256 = file_sha256(self.fmu_path)
        self._vr = {v.name: v.valueReference for v in md.modelVariables}
        causality = {v.name: v.causality for v in md.modelVariables}
        wrong = [f"{n} ({causality.get(n, 'missing')})" for n in INPUTS
                 if causality.get(n) != "input"]
        wrong += [f"{n} ({causality.get(n, 'missing')})" for n in _OUTPUTS
                  if causality.get(n) != "output"]
        if md.coSimulation is None or wrong:
            slave.remove_folder()
            raise FmuError(f"{self.fmu_path}: not a controller FMU (a co-simulation FMU with "
                           f"the inputs {', '.join(INPUTS)} and the outputs tau_r, tau_l, ...); "
                           f"wrong: {', '.join(wrong[:6]) or 'no co-simulation'}"
                           + (f" and {len(wrong) - 6} more" if len(wrong) > 6 else ""))
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

    def _bind(self) -> None:
        """The three calls of a sample bound to the prebuilt arrays (:meth:`FmuSlave.bind`),
        and this instance as the C stepper sees it (``wmr_fmu_loop``)."""
        slave = self._slave
        slave.bind(self._in_vr, self._in_val, self._out_vr, self._out_val)
        self.fmu_call = fmu_call(self.fmi_version, slave.fmu.dll, slave.fmu.component,
                                 slave.names, self._in_vr, self._in_val, self._out_vr,
                                 self._out_val)

    def _check(self, which: int, status: int) -> None:
        if status <= WARNING:
            return
        raise self._slave.status_error(which, status, self._t, ", ".join(
            f"{n} = {v!r}" for n, v in zip(INPUTS, self._in_val, strict=True)))

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
        slave = self._slave
        if slave.instantiate_or_reset():
            self._bind()
        values = controller_parameters(spec)
        unknown = [n for n in values if n not in self._vr]
        if unknown:
            raise FmuError(f"{self.fmu_path}: lacks the parameters {', '.join(unknown)}")
        self.goal_heading_rad = spec.goal.heading_rad
        self.heading_tolerance_rad = spec.heading_tolerance_rad
        self._t, self._n, self._h = 0.0, 0, spec.period_s
        slave.enter_initialization()
        slave.set_float64(f"setting the parameters {values}", [self._vr[n] for n in values],
                          list(values.values()))
        slave.exit_initialization()

    def reset(self) -> None:
        """Nothing to do: :meth:`configure` starts every run from the FMU's reset state."""

    def _converged(self, x: float, y: float, theta: float, v: float, omega: float) -> bool:
        val = self._in_val
        val[0], val[1], val[2], val[3], val[4] = x, y, theta, v, omega
        slave = self._slave
        self._check(0, slave.raw_set())
        self._check(2, slave.raw_get())
        return bool(self._outputs[_I_CONVERGED] != 0.0)

    def step(self, x: float, y: float, theta: float, omega_r: float,
             omega_l: float) -> tuple[float, ...]:
        """One control period: the sample's :data:`~wmr.core.signals.CONTROL_SIGNALS`, then doStep.

        ``v`` and ``omega`` are those of the last ``stabiliser.converged`` call (they only
        enter the convergence test).
        """
        val = self._in_val
        val[0], val[1], val[2], val[5], val[6] = x, y, theta, omega_r, omega_l
        slave = self._slave
        self._check(0, slave.raw_set())
        self._check(2, slave.raw_get())
        sig = tuple(self._outputs[:_N_SIG].tolist())
        self._check(1, slave.raw_step(self._t, self._h))
        self._n += 1
        self._t = self._n * self._h  # t_n = n h, never accumulated
        return sig

    def close(self) -> None:
        """Terminate and free the instance and remove the extraction folder
        (:meth:`FmuSlave.close`)."""
        self._slave.close()

    def __enter__(self) -> FmuController:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["FmuController", "controller_parameters"]

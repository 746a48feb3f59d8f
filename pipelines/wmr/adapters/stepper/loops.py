"""The closed loop in the C stepper: the loops an FMU plant runs for the controllers it can take.

:func:`fast_loop` is what :meth:`wmr.adapters.fmi.robot.FmuPlant.fast_loop` returns to
:func:`wmr.core.closedloop.run_closed_loop` (a :class:`wmr.core.closedloop.FastLoop`), by the
controller's ``stepper_kind`` (absent means ``""``), bit for bit the loop of the core
(``docs/architecture.md``, "The C stepper"):

* ``"servo"``: a Python law feeding two :class:`~wmr.core.control.WheelServo` s; the controller
  has ``right`` and ``left`` (the servos, of that very class) and its ``stabiliser`` has
  ``update(x, y, theta)`` (the 18 law columns, wheel references at 12 and 13). The stepper
  then runs the servos, the row and the plant step (``wmr_servo_step``).
* ``"blocks"``: the whole closed loop runs in C (the controller FMU, or the paper's law compiled
  into the stepper), without sensors: the controller has ``block_loop(lib, plant_call, state)``
  (the C call that fills the block of ``state`` and steps the plant of ``plant_call`` until the
  block is full or the run ends), ``set_clock(n)`` and ``raise_step_error(code)``.
* ``""``: none here; the core's Python loop runs.
"""

from __future__ import annotations

import ctypes
import math
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from wmr.adapters.stepper import (
    STEP_CONTROLLER,
    STEP_DONE,
    STEP_FULL,
    STEP_NONFINITE,
    LoopState,
)
from wmr.core.closedloop import (
    BLOCK_ROWS,
    FastLoop,
    LoopBlock,
    LoopTally,
    Progress,
    end_run,
)
from wmr.core.control import WheelServo
from wmr.core.runspec import RunSpec
from wmr.core.sensing import Sensing
from wmr.core.signals import COLUMN, LAW_INDEX, PLANT_SIGNALS, SIGNALS

if TYPE_CHECKING:
    from wmr.core.control import Stabiliser

_N_PLANT = len(PLANT_SIGNALS)
_N_SIG = len(SIGNALS)
_C_TAU_R = COLUMN["tau_r_nm"]
_C_TAU_L = COLUMN["tau_l_nm"]
#: The wheel references in a law's columns (by name).
_L_W_R, _L_W_L = LAW_INDEX["omega_r_ref_radps"], LAW_INDEX["omega_l_ref_radps"]


def fast_loop(plant: Any, stepper: tuple[Any, Any] | None, controller: Any,
              sensing: Sensing | None) -> FastLoop | None:
    """The stepper's loop for ``controller`` on ``plant`` (whose ``stepper()`` gave
    ``stepper``: the library and the plant's :class:`~wmr.adapters.stepper.FmuCall`), or None
    when the core's Python loop must run (no stepper, outputs not ours, a controller it cannot
    take, a ``"blocks"`` one with sensors)."""
    if stepper is None or stepper[0] is None or stepper[1].n_out != _N_PLANT:
        return None
    kind = getattr(controller, "stepper_kind", "")
    if kind == "blocks" and sensing is None:
        def blocks(spec: RunSpec, sensing: Sensing | None, out: npt.NDArray[np.float64],
                   block: LoopBlock, tally: LoopTally, progress: Progress | None) -> None:
            _fmu_loop(spec, plant, stepper, controller, block, tally, progress)
        return blocks
    if (kind == "servo" and type(getattr(controller, "right", None)) is WheelServo
            and type(getattr(controller, "left", None)) is WheelServo):
        def servo(spec: RunSpec, sensing: Sensing | None, out: npt.NDArray[np.float64],
                  block: LoopBlock, tally: LoopTally, progress: Progress | None) -> None:
            _servo_loop(spec, plant, stepper, controller, sensing, out, block, tally, progress)
        return servo
    return None


def _loop_state(spec: RunSpec, block: LoopBlock, tally: LoopTally) -> LoopState:
    st = LoopState()
    st.h = spec.period_s
    st.x_prev, st.y_prev = tally.x, tally.y  # the path starts at the start pose
    st.n_max = spec.n_steps_max
    st.block = block.rows.ctypes.data
    st.n_cols, st.rows_max, st.n_plant = _N_SIG, BLOCK_ROWS, _N_PLANT
    st.n_sig = _N_SIG - _N_PLANT
    st.col_tau_r, st.col_tau_l = _C_TAU_R, _C_TAU_L
    return st



#: Columns of the block a stabiliser fills (all but the plant outputs and the two torques).
_LAW_COLUMNS = np.array([c for c in range(_N_PLANT, _N_SIG) if c not in (_C_TAU_R, _C_TAU_L)])


def _servo_loop(spec: RunSpec, plant: Any, stepper: tuple[Any, Any],
                controller: Any, sensing: Sensing | None,
                out: npt.NDArray[np.float64], block: LoopBlock, tally: LoopTally,
                progress: Progress | None) -> None:
    """A Python law, the wheel servos and the FMU step in one C call per step.

    The stabiliser runs in Python as in the core's own loop
    (:func:`wmr.core.closedloop.run_closed_loop`); ``wmr_servo_step`` runs the two
    :class:`~wmr.core.control.WheelServo` updates, writes the row's plant outputs and torques,
    and takes the FMU step with the bookkeeping, operation for operation as in Python.  The
    law's 18 columns are gathered per row and written into the block once it is full.
    """
    lib, call = stepper
    h = spec.period_s
    n_max = spec.n_steps_max
    tol = spec.heading_tolerance_rad
    stab: Stabiliser = controller.stabiliser
    servo: WheelServo = controller.right
    st = _loop_state(spec, block, tally)
    st.k_p, st.k_i, st.torque_max, st.h_servo = servo.K_p, servo.K_i, servo.torque_max, servo.h
    st.b_ff, st.tau_c_ff, st.w_c, st.k_t = servo.b_ff, servo.tau_c_ff, servo.w_c, servo.k_t
    left = controller.left
    if (left.K_p, left.K_i, left.torque_max, left.h, left.b_ff, left.tau_c_ff, left.w_c,
            left.k_t) != (servo.K_p, servo.K_i, servo.torque_max, servo.h, servo.b_ff,
                          servo.tau_c_ff, servo.w_c, servo.k_t):
        raise ValueError("the C stepper needs two alike wheel servos")
    st.integral_r, st.integral_l = servo.integral, left.integral
    step = partial(lib.wmr_servo_step, ctypes.byref(call), ctypes.byref(st))
    o = (ctypes.c_double * _N_PLANT).from_address(call.out_val)
    laws: list[tuple[float, ...]] = []
    keep = laws.append
    converged_test, update = stab.converged, stab.update
    isfinite = math.isfinite
    n = n_first = 0
    x, y, theta = tally.x, tally.y, tally.theta
    converged = False

    def fill(rows: int) -> None:
        if rows:
            block.rows[:rows, _LAW_COLUMNS] = laws
            block.set_times(n_first, rows)
            laws.clear()

    try:
        while True:
            if not (isfinite(x) and isfinite(y) and isfinite(theta)):
                raise FloatingPointError(f"plant returned a non-finite pose at t={n * h:g} s")
            if sensing is None:
                kx, ky, ktheta = x, y, theta
                converged = converged_test(x, y, theta, o[3], o[4], tol)
            else:
                kx, ky, ktheta, kv, komega = sensing.step(n, out)
                converged = converged_test(kx, ky, ktheta, kv, komega, tol)
            law = update(kx, ky, ktheta)
            keep(law)
            code = step(law[_L_W_R], law[_L_W_L], 1 if converged else (2 if n >= n_max else 0))
            if st.row == BLOCK_ROWS:
                fill(BLOCK_ROWS)
                st.row = 0
                block.flush(BLOCK_ROWS)
                n_first = n + 1
                if progress is not None:
                    progress(n * h, spec.t_max_s)
            if code:
                plant.set_clock(h, n)
                plant.raise_step_error(code)
            if converged or n >= n_max:
                break
            n += 1
            x, y, theta = o[0], o[1], o[2]
    finally:
        fill(st.row)
        plant.set_clock(h, int(st.n))
        servo.integral, left.integral = st.integral_r, st.integral_l
        tally.n, tally.row, tally.steps = n, st.row, n_first + st.row
        tally.x, tally.y, tally.theta, tally.path = x, y, theta, st.path
        tally.energy, tally.energy_pos = st.energy_net, st.energy_pos
        tally.tau_sq, tally.peak = st.tau_sq, st.peak
    end_run(spec, tally, converged, stab.heading_error)


def _fmu_loop(spec: RunSpec, plant: Any, stepper: tuple[Any, Any],
              controller: Any, block: LoopBlock, tally: LoopTally,
              progress: Progress | None) -> None:
    """The whole closed loop in C: one call per block (``wmr_fmu_loop`` with the controller
    FMU, ``wmr_law_loop`` with the compiled law; the controller's ``block_loop``)."""
    lib, call = stepper
    h = spec.period_s
    st = _loop_state(spec, block, tally)
    run = controller.block_loop(lib, call, st)
    o = (ctypes.c_double * _N_PLANT).from_address(call.out_val)
    logged = 0  # rows of the run delivered or in the block
    code = 0
    try:
        while True:
            code = run()
            rows = st.row
            block.set_times(logged, rows)
            logged += rows
            if code != STEP_FULL:
                break
            st.row = 0
            block.flush(BLOCK_ROWS)
            if progress is not None:
                progress((logged - 1) * h, spec.t_max_s)
    finally:
        plant.set_clock(h, int(st.n))
        controller.set_clock(logged)
        tally.n, tally.row, tally.steps = int(st.n), st.row, logged
        tally.x, tally.y, tally.theta, tally.path = o[0], o[1], o[2], st.path
        tally.energy, tally.energy_pos = st.energy_net, st.energy_pos
        tally.tau_sq, tally.peak = st.tau_sq, st.peak
    if code & STEP_DONE:
        end_run(spec, tally, code == STEP_DONE | 1, controller.stabiliser.heading_error)
    elif code == STEP_NONFINITE:
        raise FloatingPointError(f"plant returned a non-finite pose at t={tally.n * h:g} s")
    elif code >= STEP_CONTROLLER:
        controller.raise_step_error(code - STEP_CONTROLLER)
    else:
        plant.raise_step_error(code)


__all__ = ["fast_loop"]

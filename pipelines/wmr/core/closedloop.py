"""The co-simulation master: one closed-loop run of a controller on any plant.

The loop takes any controller through one small protocol, :class:`Controller`, and imports
none of them: the caller builds it (the run's own Python law,
:class:`wmr.core.control.from_spec.SpecController`; the controller FMU,
:class:`wmr.adapters.fmi.controller.FmuController`; or a user's own) and the loop configures it
with the run.

Plant-agnostic: it takes a :class:`wmr.core.plant.Plant` (the FMU or the reference physics) and one
code path serves every scenario.  Per control step ``n`` at ``t_n = n h`` (exact, never
accumulated):

1. the plant outputs at ``t_n`` go into the controller: the true state (perfect state
   feedback), or, when the run has sensors (``spec.sensors``), what its estimator makes of
   their measurements (:class:`wmr.core.sensing.Sensing`; convergence is then decided on the
   estimate, as a real robot must);
2. the controller's signals and the outputs fill row ``n`` of a preallocated block laid out as
   :data:`wmr.core.signals.SIGNALS`; a full block goes to the sink;
3. the torques are held over ``[t_n, t_n + h)`` (``plant.step``).

The run ends ``converged`` (stop radius, heading aligned, nearly at rest), ``timeout`` at
``t_max``, or ``failed`` when the plant or the controller raises (never propagated, except
``KeyboardInterrupt`` and other non-``Exception`` exits).
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any, Protocol, cast

import numpy as np
import numpy.typing as npt

from wmr.core.control import WheelServo, wrap_angle
from wmr.core.energy import step_work
from wmr.core.plant import Plant, Pose
from wmr.core.runspec import RunSpec
from wmr.core.sensing import Sensing, SensingRecord
from wmr.core.signals import COLUMN, LAW_INDEX, PLANT_SIGNALS, SIGNALS

if TYPE_CHECKING:
    from wmr.core.control import Stabiliser

#: Rows per block handed to the sink.
BLOCK_ROWS = 100

_N_PLANT = len(PLANT_SIGNALS)
_N_SIG = len(SIGNALS)
_C_TAU_R = COLUMN["tau_r_nm"]
_C_TAU_L = COLUMN["tau_l_nm"]
#: The torques in a controller's signals, and the wheel references in its law's (by name).
_S_TAU_R, _S_TAU_L = _C_TAU_R - _N_PLANT, _C_TAU_L - _N_PLANT
_L_W_R, _L_W_L = LAW_INDEX["omega_r_ref_radps"], LAW_INDEX["omega_l_ref_radps"]


class BlockSink(Protocol):
    """Receives the run's rows in blocks (the MCAP writer implements it)."""

    def write_block(self, t_ns: npt.NDArray[np.int64],
                    block: npt.NDArray[np.float64]) -> None:
        """``t_ns``: (n,) log times in ns from the run's start; ``block``: (n, len(SIGNALS)).

        The arrays are reused after the call returns: copy them to keep them.
        """
        ...


class LoopStabiliser(Protocol):
    """The part of a controller's law the loop asks between steps."""

    def converged(self, x: float, y: float, theta: float, v: float, omega: float,
                  heading_tolerance_rad: float) -> bool:
        """At the goal, aligned and at rest (on the state before this step's sample): the
        loop logs a last row with zero torque and stops the run."""
        ...

    def heading_error(self, theta: float) -> float:
        """Heading minus the desired heading, wrapped, rad (the message of a timeout)."""
        ...


class Controller(Protocol):
    """What the loop calls of a controller: configure it once per run, then one ``step`` per
    control period.

    ``stepper_kind`` (optional; absent means ``""``) tells the C stepper of an FMU plant what
    it may take over, bit for bit (``docs/architecture.md``, "The C stepper"):

    * ``"servo"``: a Python law feeding two :class:`~wmr.core.control.WheelServo` s; the
      controller has ``right`` and ``left`` (the servos, of that very class) and its
      ``stabiliser`` has ``update(x, y, theta)`` (the 18 law columns, wheel references at 12
      and 13). The C stepper then runs the servos, the row and the plant step.
    * ``"blocks"``: the whole closed loop runs in C (the controller FMU, or the paper's law
      compiled into the stepper): the controller has ``block_loop(lib, plant_call, state)``
      (the C call that fills the block of ``state`` and steps the plant of ``plant_call``
      until the block is full or the run ends), ``set_clock(n)`` and
      ``raise_step_error(code)``.
    * ``""``: Python only, one ``step`` per period.
    """

    @property
    def stabiliser(self) -> LoopStabiliser:
        """The law's convergence test and heading error."""
        ...

    def configure(self, spec: RunSpec) -> None:
        """Start a run of ``spec``: take its goal and settings, forget every state."""
        ...

    def step(self, x: float, y: float, theta: float, omega_r: float,
             omega_l: float) -> tuple[float, ...]:
        """One control period: the (estimated) pose and the wheel speeds in; the
        :data:`wmr.core.signals.CONTROL_SIGNALS` out, ``tau_r, tau_l`` at 14 and 15, held
        over the period."""
        ...


#: ``progress(t_s, t_max_s)``, called once per block.
Progress = Callable[[float, float], None]


@dataclass(frozen=True)
class LoopOutcome:
    """Outcome of one closed-loop run."""

    status: str  # "converged", "timeout" or "failed"
    message: str
    final_position_error_m: float
    final_heading_error_rad: float
    time_to_goal_s: float | None
    path_length_m: float
    energy_net_j: float  # wmr.core.energy: net mechanical work of the motors, J
    energy_abs_j: float  # wmr.core.energy: driving and braking both counted, J
    torque_sq_integral: float  # integral of sum(tau^2) dt, N^2 m^2 s
    peak_torque_nm: float
    steps: int
    final_pose: Pose
    name: str = ""
    #: What the stabiliser believed at the end (equal to the true errors without sensors).
    estimated_final_position_error_m: float = math.nan
    estimated_final_heading_error_rad: float = math.nan
    #: The fixes and estimates of a run with sensors, for its log.
    sensing: SensingRecord | None = field(default=None, repr=False, compare=False)
    #: wmr.core.energy: work the motors deliver, none recovered, J (last, so that positional
    #: construction keeps its meaning)
    energy_positive_j: float = math.nan

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready fields (the ``wmr run --json`` object without the log path)."""
        d = asdict(self)
        d.pop("sensing")
        d["final_pose"] = {"x_m": self.final_pose.x_m, "y_m": self.final_pose.y_m,
                           "heading_rad": self.final_pose.heading_rad}
        return d


@dataclass
class _Tally:
    """What a run accumulates, whichever loop runs it (the loops keep it in locals while
    they run and write it back here when they stop, however they stop)."""

    n: int = 0  # the control step the plant is at
    row: int = 0  # rows of the current block
    steps: int = 0
    x: float = math.nan
    y: float = math.nan
    theta: float = math.nan
    path: float = 0.0
    energy: float = 0.0
    energy_pos: float = 0.0
    tau_sq: float = 0.0
    peak: float = 0.0
    status: str = "failed"
    message: str = ""
    time_to_goal: float | None = None


class _Block:
    """The preallocated block of rows and its delivery to the sink."""

    def __init__(self, h_s: float, sink: BlockSink | None) -> None:
        self.rows = np.zeros((BLOCK_ROWS, _N_SIG), dtype=np.float64)
        self.t_ns = np.zeros(BLOCK_ROWS, dtype=np.int64)
        self.h_ns = h_s * 1e9
        self.sink = sink

    def set_times(self, n_first: int, rows: int) -> None:
        """Log times of rows ``0..rows-1`` holding steps ``n_first, n_first + 1, ...``: the
        ``round(n * h_ns)`` of the per-row path (numpy's rint also rounds half to even)."""
        self.t_ns[:rows] = np.rint(np.arange(n_first, n_first + rows) * self.h_ns)

    def flush(self, rows: int) -> None:
        if self.sink is not None and rows:
            self.sink.write_block(self.t_ns[:rows], self.rows[:rows])


def _stepper(plant: Plant) -> tuple[Any, Any] | None:
    """The plant's C stepper (:meth:`wmr.adapters.fmi.robot.FmuPlant.stepper`), if it has one
    and its outputs are the plant outputs in our order."""
    get = getattr(plant, "stepper", None)
    found = get() if get is not None else None
    if found is None or found[1].n_out != _N_PLANT:
        return None
    return cast("tuple[Any, Any]", found)


class LoopState(ctypes.Structure):
    """What the C stepper (``fmu/src/stepper/wmr_stepper.c``, ``wmr_loop``) keeps of a run: the
    wheel servos, the accumulators, the clock and the row of the block being written."""

    _fields_ = [*((name, ctypes.c_double) for name in (
        "k_p", "k_i", "torque_max", "h_servo", "b_ff", "tau_c_ff", "w_c", "k_t",
        "integral_r", "integral_l", "energy_net", "energy_pos", "tau_sq", "peak", "h",
        "path", "x_prev", "y_prev")),
        ("n", ctypes.c_longlong), ("n_max", ctypes.c_longlong),
        ("block", ctypes.c_void_p),
        *((name, ctypes.c_int) for name in (
            "n_cols", "row", "rows_max", "n_plant", "n_sig", "col_tau_r", "col_tau_l",
            "i_converged"))]


#: Status codes of the stepper besides a failed FMI call's ``16 * (call + 1) + status``.
STEP_CONTROLLER, STEP_NONFINITE, STEP_DONE, STEP_FULL = 64, 256, 512, 1024


def _loop_state(spec: RunSpec, block: _Block, tally: _Tally) -> LoopState:
    st = LoopState()
    st.h = spec.period_s
    st.x_prev, st.y_prev = tally.x, tally.y  # the path starts at the start pose
    st.n_max = spec.n_steps_max
    st.block = block.rows.ctypes.data
    st.n_cols, st.rows_max, st.n_plant = _N_SIG, BLOCK_ROWS, _N_PLANT
    st.n_sig = _N_SIG - _N_PLANT
    st.col_tau_r, st.col_tau_l = _C_TAU_R, _C_TAU_L
    return st


def run_closed_loop(spec: RunSpec, plant: Plant, sink: BlockSink | None = None,
                    progress: Progress | None = None, *,
                    controller: Controller) -> LoopOutcome:
    """Simulate one run of ``spec`` on ``plant`` driven by ``controller``; write rows to
    ``sink`` if given.

    The plant is reset and the controller configured with ``spec`` here, but neither is
    closed (the caller owns them).  The run's own Python law is
    ``controller=SpecController()`` (:mod:`wmr.core.control.from_spec`).

    Three loops give the same bits (``docs/architecture.md``): with the C stepper of an FMU
    plant (:func:`wmr.adapters.fmi.robot.load_stepper`), a ``"servo"`` controller
    (:class:`Controller`) drives the wheel servos, the row and the FMU step through one C call
    per step, and a ``"blocks"`` one (the controller FMU) runs whole blocks of the closed loop
    in C; any other plant, controller or a run with sensors steps through the plant's and the
    controller's Python interfaces.
    """
    h = spec.period_s
    goal = spec.goal
    xd, yd = goal.x_m, goal.y_m
    block = _Block(h, sink)
    tally = _Tally()
    sensing: Sensing | None = None
    try:
        controller.configure(spec)
        kind = getattr(controller, "stepper_kind", "")
        out = plant.reset(spec.params, spec.start)
        if spec.sensors is not None:
            sensing = Sensing(spec.sensors, h, spec.params, spec.start, spec.goal)
        tally.x, tally.y, tally.theta = float(out[0]), float(out[1]), float(out[2])
        stepper = _stepper(plant)
        if stepper is not None and kind == "blocks" and sensing is None:
            _fmu_loop(spec, plant, stepper, controller, block, tally, progress)
        elif (stepper is not None and kind == "servo"
              and type(getattr(controller, "right", None)) is WheelServo
              and type(getattr(controller, "left", None)) is WheelServo):
            _servo_loop(spec, plant, stepper, controller, sensing, out, block, tally,
                        progress)
        else:
            _python_loop(spec, plant, controller, sensing, out, block, tally, progress)
        rows_left, tally.row = tally.row, 0
        block.flush(rows_left)
    except Exception as exc:  # a plant or controller failure ends the run, never the caller
        tally.status = "failed"
        tally.message = f"{type(exc).__name__} at t = {tally.n * h:g} s: {exc}"
        try:  # keep the rows recorded before the failure
            block.flush(tally.row)
        except Exception as sink_exc:
            tally.message += f"; and the sink failed: {sink_exc}"
    if progress is not None:
        progress(min(tally.n * h, spec.t_max_s), spec.t_max_s)

    x, y, theta = tally.x, tally.y, tally.theta
    pos_err = math.hypot(xd - x, yd - y) if math.isfinite(x) and math.isfinite(y) else math.nan
    head_err = abs(wrap_angle(theta - goal.heading_rad)) if math.isfinite(theta) else math.nan
    est_pos_err, est_head_err = pos_err, head_err
    if sensing is not None:
        known = sensing.pose
        est_pos_err = math.hypot(xd - known.x_m, yd - known.y_m)
        est_head_err = abs(wrap_angle(known.heading_rad - goal.heading_rad))
    return LoopOutcome(status=tally.status, message=tally.message,
                     final_position_error_m=pos_err,
                     final_heading_error_rad=head_err, time_to_goal_s=tally.time_to_goal,
                     path_length_m=tally.path, energy_net_j=tally.energy,
                     energy_positive_j=tally.energy_pos,
                     energy_abs_j=2.0 * tally.energy_pos - tally.energy,
                     torque_sq_integral=tally.tau_sq,
                     peak_torque_nm=tally.peak, steps=tally.steps,
                     final_pose=Pose(x, y, theta),
                     name=spec.name, estimated_final_position_error_m=est_pos_err,
                     estimated_final_heading_error_rad=est_head_err,
                     sensing=None if sensing is None else sensing.record())


def _end(spec: RunSpec, tally: _Tally, converged: bool, heading_error: Callable[[float], float]
         ) -> None:
    """The status and message of a run that stops at step ``tally.n``."""
    n, h = tally.n, spec.period_s
    if converged:
        tally.status = "converged"
        tally.time_to_goal = n * h
        tally.message = f"converged at t = {n * h:.2f} s"
    else:
        tally.status = "timeout"
        distance = math.hypot(spec.goal.x_m - tally.x, spec.goal.y_m - tally.y)
        tally.message = (f"not converged within max_time_s = {spec.t_max_s:g} s "
                         f"(distance {distance:.3f} m, heading error "
                         f"{math.degrees(abs(heading_error(tally.theta))):.2f} deg)")


def _python_loop(spec: RunSpec, plant: Plant, controller: Controller,
                 sensing: Sensing | None, out: npt.NDArray[np.float64], block: _Block,
                 tally: _Tally, progress: Progress | None) -> None:
    """Any plant, any controller: one call of each interface per step."""
    h = spec.period_s
    n_max = spec.n_steps_max
    tol = spec.heading_tolerance_rad
    stab = controller.stabiliser
    rows, t_ns, h_ns = block.rows, block.t_ns, block.h_ns
    row = n = 0
    path = energy = energy_pos = tau_sq = peak = 0.0
    x, y, theta = tally.x, tally.y, tally.theta
    w_r_prev, w_l_prev = float(out[5]), float(out[6])
    tau_r_prev = tau_l_prev = 0.0
    converged = False
    try:
        while True:
            v, omega = float(out[3]), float(out[4])
            w_r, w_l = float(out[5]), float(out[6])
            if n:  # the work of the torques held over the last step
                net, pos, _ = step_work(h, tau_r_prev, tau_l_prev, w_r_prev, w_r, w_l_prev, w_l)
                energy += net
                energy_pos += pos
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):
                raise FloatingPointError(f"plant returned a non-finite pose at t={n * h:g} s")
            if sensing is None:
                kx, ky, ktheta = x, y, theta
                converged = stab.converged(x, y, theta, v, omega, tol)
            else:
                kx, ky, ktheta, kv, komega = sensing.step(n, out)
                converged = stab.converged(kx, ky, ktheta, kv, komega, tol)
            if converged:
                # the last row shows the robot at rest with zero torque
                sig: tuple[float, ...] = controller.step(kx, ky, ktheta, w_r, w_l)
                sig = (*sig[:_S_TAU_R], 0.0, 0.0, *sig[_S_TAU_L + 1:])
            else:
                sig = controller.step(kx, ky, ktheta, w_r, w_l)
            rows[row, :_N_PLANT] = out
            rows[row, _N_PLANT:] = sig
            t_ns[row] = round(n * h_ns)
            row += 1
            tally.steps = n + 1
            if row == BLOCK_ROWS:
                row = 0
                block.flush(BLOCK_ROWS)
                if progress is not None:
                    progress(n * h, spec.t_max_s)
            if converged or n >= n_max:
                break
            tau_r, tau_l = sig[_S_TAU_R], sig[_S_TAU_L]
            a_r, a_l = abs(tau_r), abs(tau_l)
            if a_r > peak:
                peak = a_r
            if a_l > peak:
                peak = a_l
            tau_sq += (tau_r * tau_r + tau_l * tau_l) * h
            out = plant.step(tau_r, tau_l, h)
            n += 1
            nx, ny, theta = float(out[0]), float(out[1]), float(out[2])
            path += math.hypot(nx - x, ny - y)
            x, y = nx, ny
            w_r_prev, w_l_prev = w_r, w_l
            tau_r_prev, tau_l_prev = tau_r, tau_l
    finally:
        tally.n, tally.row, tally.x, tally.y, tally.theta = n, row, x, y, theta
        tally.path, tally.energy, tally.energy_pos = path, energy, energy_pos
        tally.tau_sq, tally.peak = tau_sq, peak
    _end(spec, tally, converged, stab.heading_error)


#: Columns of the block a stabiliser fills (all but the plant outputs and the two torques).
_LAW_COLUMNS = np.array([c for c in range(_N_PLANT, _N_SIG) if c not in (_C_TAU_R, _C_TAU_L)])


def _servo_loop(spec: RunSpec, plant: Plant, stepper: tuple[Any, Any],
                controller: Any, sensing: Sensing | None,
                out: npt.NDArray[np.float64], block: _Block, tally: _Tally,
                progress: Progress | None) -> None:
    """A Python law, the wheel servos and the FMU step in one C call per step.

    The stabiliser runs in Python as in :func:`_python_loop`; ``wmr_servo_step`` runs the two
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
                plant.set_clock(h, n)  # type: ignore[attr-defined]
                plant.raise_step_error(code)  # type: ignore[attr-defined]
            if converged or n >= n_max:
                break
            n += 1
            x, y, theta = o[0], o[1], o[2]
    finally:
        fill(st.row)
        plant.set_clock(h, int(st.n))  # type: ignore[attr-defined]
        servo.integral, left.integral = st.integral_r, st.integral_l
        tally.n, tally.row, tally.steps = n, st.row, n_first + st.row
        tally.x, tally.y, tally.theta, tally.path = x, y, theta, st.path
        tally.energy, tally.energy_pos = st.energy_net, st.energy_pos
        tally.tau_sq, tally.peak = st.tau_sq, st.peak
    _end(spec, tally, converged, stab.heading_error)


def _fmu_loop(spec: RunSpec, plant: Plant, stepper: tuple[Any, Any],
              controller: Any, block: _Block, tally: _Tally,
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
        plant.set_clock(h, int(st.n))  # type: ignore[attr-defined]
        controller.set_clock(logged)
        tally.n, tally.row, tally.steps = int(st.n), st.row, logged
        tally.x, tally.y, tally.theta, tally.path = o[0], o[1], o[2], st.path
        tally.energy, tally.energy_pos = st.energy_net, st.energy_pos
        tally.tau_sq, tally.peak = st.tau_sq, st.peak
    if code & STEP_DONE:
        _end(spec, tally, code == STEP_DONE | 1, controller.stabiliser.heading_error)
    elif code == STEP_NONFINITE:
        raise FloatingPointError(f"plant returned a non-finite pose at t={tally.n * h:g} s")
    elif code >= STEP_CONTROLLER:
        controller.raise_step_error(code - STEP_CONTROLLER)
    else:
        plant.raise_step_error(code)  # type: ignore[attr-defined]


__all__ = [
    "BLOCK_ROWS",
    "BlockSink",
    "Controller",
    "LoopOutcome",
    "LoopStabiliser",
    "LoopState",
    "Progress",
    "run_closed_loop",
]

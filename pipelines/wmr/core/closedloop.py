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

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from wmr.core.control import wrap_angle
from wmr.core.energy import step_work
from wmr.core.plant import Plant, Pose
from wmr.core.runspec import RunSpec
from wmr.core.sensing import Sensing, SensingRecord
from wmr.core.signals import COLUMN, LAW_INDEX, PLANT_SIGNALS, SIGNALS

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
    """Receives the run's rows in blocks: the narrow protocol the loop writes to.

    Every run log (:class:`wmr.core.runlog.RunLog`: the MCAP writer, the in-memory
    :class:`wmr.core.runlog.MemoryLog`) is one; so are the live view and the filters of a
    log policy (:mod:`wmr.apps.run`).
    """

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

    A plant may run the loop faster for some controllers (:class:`FastLoop`: the FMU plant's
    C stepper, :mod:`wmr.adapters.stepper.loops`, which reads the controller's optional
    ``stepper_kind``); the loop itself asks nothing more of a controller than this protocol.
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


#: ``progress(t_s, t_max_s)``, called once per block and once when the run ended; what it
#: raises, at any call, is the run's failure (a batch's wall-clock limit stops runs so).
Progress = Callable[[float, float], None]


class FastLoop(Protocol):
    """A plant's own loop for one run (``plant.fast_loop(controller, sensing)`` returns it, or
    None when it cannot take that controller): it runs the run from the outputs ``out`` of the
    reset, fills and flushes ``block`` as :func:`run_closed_loop`'s Python loop does, keeps
    ``tally`` up to date however it stops, and ends it with :func:`end_run`; it raises what
    the plant or the controller raised."""

    def __call__(self, spec: RunSpec, sensing: Sensing | None, out: npt.NDArray[np.float64],
                 block: LoopBlock, tally: LoopTally, progress: Progress | None) -> None: ...


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
class LoopTally:
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


class LoopBlock:
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


def run_closed_loop(spec: RunSpec, plant: Plant, sink: BlockSink | None = None,
                    progress: Progress | None = None, *,
                    controller: Controller) -> LoopOutcome:
    """Simulate one run of ``spec`` on ``plant`` driven by ``controller``; write rows to
    ``sink`` if given.

    The plant is reset and the controller configured with ``spec`` here, but neither is
    closed (the caller owns them).  The run's own Python law is
    ``controller=SpecController()`` (:mod:`wmr.core.control.from_spec`).

    A plant with a ``fast_loop(controller, sensing)`` that returns a :class:`FastLoop` runs
    the run in it (the FMU plant's C stepper: :mod:`wmr.adapters.stepper.loops`, the same
    bits, ``docs/architecture.md``); any other plant, or a controller it cannot take, steps
    through the plant's and the controller's Python interfaces here.
    """
    h = spec.period_s
    goal = spec.goal
    xd, yd = goal.x_m, goal.y_m
    block = LoopBlock(h, sink)
    tally = LoopTally()
    sensing: Sensing | None = None
    try:
        controller.configure(spec)
        out = plant.reset(spec.params, spec.start)
        if spec.sensors is not None:
            sensing = Sensing(spec.sensors, h, spec.params, spec.start, spec.goal)
        tally.x, tally.y, tally.theta = float(out[0]), float(out[1]), float(out[2])
        fast = getattr(plant, "fast_loop", None)
        loop: FastLoop | None = fast(controller, sensing) if fast is not None else None
        if loop is not None:
            loop(spec, sensing, out, block, tally, progress)
        else:
            _python_loop(spec, plant, controller, sensing, out, block, tally, progress)
        rows_left, tally.row = tally.row, 0
        block.flush(rows_left)
        if progress is not None:
            # inside the try: a callback that stops runs (a batch's wall-clock limit) may
            # raise at this last report as at any other, and that is the run's failure, never
            # an exception out of the loop (it escaped, and a batch logged the run failed
            # where its journal said timeout, then ran it again on resume)
            progress(min(tally.n * h, spec.t_max_s), spec.t_max_s)
    except Exception as exc:  # a plant or controller failure ends the run, never the caller
        tally.status = "failed"
        tally.message = f"{type(exc).__name__} at t = {tally.n * h:g} s: {exc}"
        try:  # keep the rows recorded before the failure
            block.flush(tally.row)
        except Exception as sink_exc:
            tally.message += f"; and the sink failed: {sink_exc}"

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


def end_run(spec: RunSpec, tally: LoopTally, converged: bool,
            heading_error: Callable[[float], float]) -> None:
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
                 sensing: Sensing | None, out: npt.NDArray[np.float64], block: LoopBlock,
                 tally: LoopTally, progress: Progress | None) -> None:
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
    end_run(spec, tally, converged, stab.heading_error)


__all__ = [
    "BLOCK_ROWS",
    "BlockSink",
    "Controller",
    "FastLoop",
    "LoopBlock",
    "LoopOutcome",
    "LoopStabiliser",
    "LoopTally",
    "Progress",
    "end_run",
    "run_closed_loop",
]

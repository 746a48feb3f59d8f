"""The co-simulation master: one closed-loop run of a controller on any plant.

The controller is the paper's PI stabiliser by default, or a peer (``spec.controller``, built
by :func:`wmr.core.control.peers.make_controller`), or the controller FMU
(:class:`wmr.adapters.fmi.controller.FmuController`, the same law in C) when one is given.

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
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from wmr.config.scenario import RunSpec
from wmr.core.control import wrap_angle
from wmr.core.control.peers import make_controller
from wmr.core.energy import step_work
from wmr.core.plant import Plant, Pose
from wmr.core.sensing import Sensing, SensingRecord
from wmr.core.signals import COLUMN, PLANT_SIGNALS, SIGNALS

if TYPE_CHECKING:
    from wmr.adapters.fmi.controller import FmuController
    from wmr.core.control import ServoedController

#: Rows per block handed to the sink.
BLOCK_ROWS = 100

_N_PLANT = len(PLANT_SIGNALS)
_N_SIG = len(SIGNALS)
_C_TAU_R = COLUMN["tau_r_nm"]
_C_TAU_L = COLUMN["tau_l_nm"]


class BlockSink(Protocol):
    """Receives the run's rows in blocks (the MCAP writer implements it)."""

    def write_block(self, t_ns: npt.NDArray[np.int64],
                    block: npt.NDArray[np.float64]) -> None:
        """``t_ns``: (n,) log times in ns from the run's start; ``block``: (n, len(SIGNALS)).

        The arrays are reused after the call returns: copy them to keep them.
        """
        ...


#: ``progress(t_s, t_max_s)``, called once per block.
Progress = Callable[[float, float], None]


@dataclass(frozen=True)
class RunResult:
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


def run_closed_loop(spec: RunSpec, plant: Plant, sink: BlockSink | None = None,
                    progress: Progress | None = None,
                    controller_fmu: FmuController | None = None) -> RunResult:
    """Simulate one run of ``spec`` on ``plant``; write rows to ``sink`` if given.

    The plant (and ``controller_fmu``, which replaces the Python controller when given) is
    reset here but not closed (the caller owns it).
    """
    h = spec.period_s
    n_max = spec.n_steps_max
    goal = spec.goal
    xd, yd = goal.x_m, goal.y_m
    tol = spec.heading_tolerance_rad
    block = np.zeros((BLOCK_ROWS, _N_SIG), dtype=np.float64)
    t_ns = np.zeros(BLOCK_ROWS, dtype=np.int64)
    h_ns = h * 1e9

    status = "failed"
    message = ""
    steps = 0
    row = 0
    path = 0.0
    energy = 0.0
    energy_pos = 0.0
    tau_sq = 0.0
    peak = 0.0
    time_to_goal: float | None = None
    x = y = theta = math.nan
    n = 0
    sensing: Sensing | None = None

    def flush(rows: int) -> None:
        if sink is not None and rows:
            sink.write_block(t_ns[:rows], block[:rows])

    try:
        controller: ServoedController | FmuController
        if controller_fmu is not None:
            controller_fmu.configure(spec)
            controller = controller_fmu
        else:
            controller = make_controller(spec.controller, goal, spec.gains, spec.limits,
                                         spec.params, h, spec.stop_radius_m,
                                         dict(spec.controller_gains))
        stab = controller.stabiliser
        out = plant.reset(spec.params, spec.start)
        if spec.sensors is not None:
            sensing = Sensing(spec.sensors, h, spec.params, spec.start, spec.goal)
        x, y, theta = float(out[0]), float(out[1]), float(out[2])
        w_r_prev, w_l_prev = float(out[5]), float(out[6])
        tau_r_prev = tau_l_prev = 0.0
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
                sig = (*sig[:14], 0.0, 0.0, *sig[16:])
            else:
                sig = controller.step(kx, ky, ktheta, w_r, w_l)
            block[row, :_N_PLANT] = out
            block[row, _N_PLANT:] = sig
            t_ns[row] = round(n * h_ns)
            row += 1
            steps = n + 1
            if row == BLOCK_ROWS:
                row = 0
                flush(BLOCK_ROWS)
                if progress is not None:
                    progress(n * h, spec.t_max_s)
            if converged:
                status = "converged"
                time_to_goal = n * h
                message = f"converged at t = {n * h:.2f} s"
                break
            if n >= n_max:
                status = "timeout"
                message = (f"not converged within max_time_s = {spec.t_max_s:g} s "
                           f"(distance {math.hypot(xd - x, yd - y):.3f} m, heading error "
                           f"{math.degrees(abs(stab.heading_error(theta))):.2f} deg)")
                break
            tau_r, tau_l = sig[_C_TAU_R - _N_PLANT], sig[_C_TAU_L - _N_PLANT]
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
        rows_left, row = row, 0
        flush(rows_left)
    except Exception as exc:  # a plant or controller failure ends the run, never the caller
        status = "failed"
        message = f"{type(exc).__name__} at t = {n * h:g} s: {exc}"
        try:  # keep the rows recorded before the failure
            flush(row)
        except Exception as sink_exc:
            message += f"; and the sink failed: {sink_exc}"
    if progress is not None:
        progress(min(n * h, spec.t_max_s), spec.t_max_s)

    pos_err = math.hypot(xd - x, yd - y) if math.isfinite(x) and math.isfinite(y) else math.nan
    head_err = abs(wrap_angle(theta - goal.heading_rad)) if math.isfinite(theta) else math.nan
    est_pos_err, est_head_err = pos_err, head_err
    if sensing is not None:
        known = sensing.pose
        est_pos_err = math.hypot(xd - known.x_m, yd - known.y_m)
        est_head_err = abs(wrap_angle(known.heading_rad - goal.heading_rad))
    return RunResult(status=status, message=message, final_position_error_m=pos_err,
                     final_heading_error_rad=head_err, time_to_goal_s=time_to_goal,
                     path_length_m=path, energy_net_j=energy,
                     energy_positive_j=energy_pos, energy_abs_j=2.0 * energy_pos - energy,
                     torque_sq_integral=tau_sq,
                     peak_torque_nm=peak, steps=steps, final_pose=Pose(x, y, theta),
                     name=spec.name, estimated_final_position_error_m=est_pos_err,
                     estimated_final_heading_error_rad=est_head_err,
                     sensing=None if sensing is None else sensing.record())


__all__ = ["BLOCK_ROWS", "BlockSink", "Progress", "RunResult", "run_closed_loop"]

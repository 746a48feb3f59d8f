"""The record of a run (``docs/results.md``, "The record of a run"): one builder for every path.

``wmr run --json``, the ``result`` metadata of every log that holds a robot path (``wmr run``,
``wmr batch``, ``wmr benchmark --out``, ``wmr ssp run``, ``wmr optimal``) and a batch summary's
row all carry :data:`RECORD_KEYS`, in that order, built here: :func:`result_record` from a
closed-loop :class:`~wmr.core.closedloop.LoopOutcome`, :func:`record` from the figures of a run
another master made (an SSP master, the optimal's open-loop replay).  A path's own fields
follow these keys.  Non-finite figures are ``None`` (JSON ``null``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Final

if TYPE_CHECKING:
    from wmr.core.closedloop import LoopOutcome

#: The keys of the record, in order (the table of ``docs/results.md``).
RECORD_KEYS: Final = (
    "name", "status", "message", "final_position_error_m", "final_heading_error_rad",
    "time_to_goal_s", "path_length_m", "energy_net_j", "energy_positive_j", "energy_abs_j",
    "torque_sq_integral_n2m2s", "peak_torque_nm", "steps", "estimated_final_position_error_m",
    "estimated_final_heading_error_rad", "mcap",
)


def jsonable(value: float | None) -> float | None:
    """``value`` as a JSON number: ``None`` for None, NaN and the infinities."""
    return None if value is None or not math.isfinite(value) else float(value)


def record(*, name: str, status: str, message: str, final_position_error_m: float | None,
           final_heading_error_rad: float | None, time_to_goal_s: float | None,
           path_length_m: float | None, energy_net_j: float | None,
           energy_positive_j: float | None, energy_abs_j: float | None,
           torque_sq_integral_n2m2s: float | None, peak_torque_nm: float | None, steps: int,
           estimated_final_position_error_m: float | None = math.nan,
           estimated_final_heading_error_rad: float | None = math.nan,
           mcap: str | None = None) -> dict[str, Any]:
    """The record of a run from its figures (units in the names; ``docs/results.md``).

    ``estimated_*``: what the run's stabiliser believed at the end; a run without sensors
    passes the true errors.
    """
    return {
        "name": name,
        "status": status,
        "message": message,
        "final_position_error_m": jsonable(final_position_error_m),
        "final_heading_error_rad": jsonable(final_heading_error_rad),
        "time_to_goal_s": jsonable(time_to_goal_s),
        "path_length_m": jsonable(path_length_m),
        "energy_net_j": jsonable(energy_net_j),
        "energy_positive_j": jsonable(energy_positive_j),
        "energy_abs_j": jsonable(energy_abs_j),
        "torque_sq_integral_n2m2s": jsonable(torque_sq_integral_n2m2s),
        "peak_torque_nm": jsonable(peak_torque_nm),
        "steps": steps,
        "estimated_final_position_error_m": jsonable(estimated_final_position_error_m),
        "estimated_final_heading_error_rad": jsonable(estimated_final_heading_error_rad),
        "mcap": mcap,
    }


def result_record(name: str, result: LoopOutcome) -> dict[str, Any]:
    """The record of a closed-loop run (``mcap`` None: the caller sets the log's path)."""
    return record(
        name=name, status=result.status, message=result.message,
        final_position_error_m=result.final_position_error_m,
        final_heading_error_rad=result.final_heading_error_rad,
        time_to_goal_s=result.time_to_goal_s, path_length_m=result.path_length_m,
        energy_net_j=result.energy_net_j, energy_positive_j=result.energy_positive_j,
        energy_abs_j=result.energy_abs_j, torque_sq_integral_n2m2s=result.torque_sq_integral,
        peak_torque_nm=result.peak_torque_nm, steps=result.steps,
        estimated_final_position_error_m=result.estimated_final_position_error_m,
        estimated_final_heading_error_rad=result.estimated_final_heading_error_rad)


__all__ = ["RECORD_KEYS", "jsonable", "record", "result_record"]

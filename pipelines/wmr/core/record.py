"""The record of a run (``docs/results.md``, "The record of a run"): one builder for every path.

``wmr run --json``, the ``result`` metadata of every log that holds a robot path (``wmr run``,
``wmr batch``, ``wmr benchmark --out``, ``wmr ssp run``, ``wmr optimal``) and a batch summary's
row all carry :data:`RECORD_KEYS`, in that order, built here: :func:`result_record` from a
closed-loop :class:`~wmr.core.closedloop.LoopOutcome`, :func:`record` from the
:class:`RunFigures` of a run another master made (an SSP master, the optimal's open-loop
replay).  A path's own fields follow these keys.  Non-finite figures are ``None`` (JSON ``null``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, Final

if TYPE_CHECKING:
    from wmr.core.closedloop import LoopOutcome

@dataclass(frozen=True)
class RunFigures:
    """The figures of one run, in the record's order (the table of ``docs/results.md``; units
    in the names); :func:`record` makes them the record.

    Attributes
    ----------
    name, status, message
        The run's name, how it ended (``converged``, ``timeout``, ...; an optimal manoeuvre's
        solver status) and the one line that says why.
    final_position_error_m, final_heading_error_rad
        The true errors at the end, m and rad.
    time_to_goal_s, path_length_m
        When the run ended at the goal, s, and the path length of B, m.
    energy_net_j, energy_positive_j, energy_abs_j
        The motors' net, positive and absolute work, J (:mod:`wmr.core.energy`).
    torque_sq_integral_n2m2s, peak_torque_nm
        The integral of the squared wheel torques, N^2 m^2 s, and the largest torque, N.m.
    steps
        The rows of the run.
    estimated_final_position_error_m, estimated_final_heading_error_rad
        What the run's stabiliser believed at the end; a run without sensors gives the true
        errors (NaN: not known).
    mcap
        The log's path; None when no log was kept (the caller sets it after the log).
    """

    name: str
    status: str
    message: str
    final_position_error_m: float | None
    final_heading_error_rad: float | None
    time_to_goal_s: float | None
    path_length_m: float | None
    energy_net_j: float | None
    energy_positive_j: float | None
    energy_abs_j: float | None
    torque_sq_integral_n2m2s: float | None
    peak_torque_nm: float | None
    steps: int
    estimated_final_position_error_m: float | None = math.nan
    estimated_final_heading_error_rad: float | None = math.nan
    mcap: str | None = None


#: The keys of the record, in order (the table of ``docs/results.md``): the fields of
#: :class:`RunFigures`.
RECORD_KEYS: Final = tuple(f.name for f in fields(RunFigures))
#: The keys a record holds as given; every other is a figure, ``None`` when not finite.
_AS_GIVEN: Final = frozenset({"name", "status", "message", "steps", "mcap"})


def jsonable(value: float | None) -> float | None:
    """``value`` as a JSON number: ``None`` for None, NaN and the infinities."""
    return None if value is None or not math.isfinite(value) else float(value)


def record(figures: RunFigures) -> dict[str, Any]:
    """The record of a run from its figures: :data:`RECORD_KEYS` in order, each non-finite
    figure ``None`` (JSON ``null``)."""
    return {key: getattr(figures, key) if key in _AS_GIVEN else jsonable(getattr(figures, key))
            for key in RECORD_KEYS}


def result_record(name: str, result: LoopOutcome) -> dict[str, Any]:
    """The record of a closed-loop run (``mcap`` None: the caller sets the log's path)."""
    return record(RunFigures(
        name=name, status=result.status, message=result.message,
        final_position_error_m=result.final_position_error_m,
        final_heading_error_rad=result.final_heading_error_rad,
        time_to_goal_s=result.time_to_goal_s, path_length_m=result.path_length_m,
        energy_net_j=result.energy_net_j, energy_positive_j=result.energy_positive_j,
        energy_abs_j=result.energy_abs_j, torque_sq_integral_n2m2s=result.torque_sq_integral,
        peak_torque_nm=result.peak_torque_nm, steps=result.steps,
        estimated_final_position_error_m=result.estimated_final_position_error_m,
        estimated_final_heading_error_rad=result.estimated_final_heading_error_rad))


__all__ = ["RECORD_KEYS", "RunFigures", "jsonable", "record", "result_record"]

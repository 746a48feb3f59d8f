"""A simulation and a real robot's log of the same manoeuvre in one replay.

``wmr replay SIM.mcap REAL.mcap``: a pose-only log (a real robot's,
:attr:`wmr.adapters.mcap.RunData.pose_topic`) replayed with one of ours is put on the
simulation's time axis by the start of motion of both (:func:`wmr.core.compare.motion_start_s`),
and the distance between the two paths at the same aligned time
(:func:`wmr.core.compare.path_deviation_m`) is a panel of its own.  The reference is the first
of our logs given; every pose-only log is aligned to it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import NDArray

from wmr.adapters.mcap import RunData
from wmr.core.compare import (
    MOTION_THRESHOLD_M,
    MOTION_THRESHOLD_RAD,
    motion_start_s,
    path_deviation_m,
)

#: The deviation's entity under a pose-only run's subtree: ``runs/<name>/deviation``.
DEVIATION_ENTITY: Final = "deviation"

Rgb = tuple[int, int, int]
_INT64_MAX: Final = 2**63 - 1


@dataclass(frozen=True)
class Alignment:
    """How a pose-only run was put on the reference run's time axis."""

    #: Indexes of the aligned run and of the reference (a run of ours) in the replay.
    run: int
    reference: int
    #: Added to the aligned run's times, s: its start of motion falls on the reference's.
    shift_s: float
    #: The reference's start of motion, s (on the common axis).
    start_s: float
    #: The aligned run's times inside the reference's span (s) and the distance between the
    #: two positions there (m).
    t_s: NDArray[np.float64]
    deviation_m: NDArray[np.float64]


def _start(data: RunData) -> float | None:
    s = data.signals
    return motion_start_s(data.t_s, s["x_m"], s["y_m"], s["theta_rad"])


def align_runs(names: Sequence[str], datas: Sequence[RunData]
               ) -> tuple[list[RunData], list[Alignment], list[str]]:
    """Put every pose-only run on the time axis of the first run of ours, by their starts
    of motion, and measure how far apart the two paths are at each aligned time.

    Parameters
    ----------
    names
        The runs' names (for the warnings).
    datas
        The runs, in the order given.

    Returns
    -------
    (runs, alignments, warnings)
        The runs, the pose-only ones with their times shifted; one :class:`Alignment` per
        aligned run; one line per pose-only run that could not be aligned (it or the
        reference never moves), which is then replayed from its first pose.
    """
    ours = [k for k, d in enumerate(datas) if d.pose_topic is None]
    real = [k for k, d in enumerate(datas) if d.pose_topic is not None]
    out = list(datas)
    if not ours or not real:
        return out, [], []
    ref = ours[0]
    ref_data = datas[ref]
    ref_start = _start(ref_data)
    alignments: list[Alignment] = []
    warnings: list[str] = []
    moved = (f"{MOTION_THRESHOLD_M * 100:g} cm or {np.degrees(MOTION_THRESHOLD_RAD):g} deg "
             "from its first pose")
    for k in real:
        start = _start(datas[k])
        if ref_start is None or start is None:
            still = names[ref] if ref_start is None else names[k]
            warnings.append(f"{names[k]} is not aligned to {names[ref]}: {still} never moves "
                            f"{moved}; replayed from its first pose")
            continue
        shift_ns = round((ref_start - start) * 1e9)
        t_ns = datas[k].t_ns
        # a stranger's times may reach 2^63 ns: shifted past it they would wrap around
        if int(t_ns[-1]) + shift_ns > _INT64_MAX or int(t_ns[0]) + shift_ns < -_INT64_MAX:
            warnings.append(f"{names[k]} is not aligned to {names[ref]}: its times shifted "
                            f"by {shift_ns * 1e-9:+.3f} s would leave the int64 range of ns; "
                            "replayed from its first pose")
            continue
        shifted = dataclasses.replace(datas[k], t_ns=t_ns + np.int64(shift_ns))
        out[k] = shifted
        t, dev = path_deviation_m(
            ref_data.t_s, np.column_stack([ref_data.signals["x_m"], ref_data.signals["y_m"]]),
            shifted.t_s, np.column_stack([shifted.signals["x_m"], shifted.signals["y_m"]]))
        alignments.append(Alignment(run=k, reference=ref, shift_s=shift_ns * 1e-9,
                                    start_s=ref_start, t_s=t, deviation_m=dev))
    return out, alignments, warnings


def log_deviation(rec: rr.RecordingStream, root: str, timeline: str, label: str,
                  color: Rgb, alignment: Alignment) -> None:
    """Send the deviation of an aligned run as ``<root>/deviation`` (Scalars on ``timeline``,
    a duration), its line named ``label`` in ``color``."""
    entity = f"{root}/{DEVIATION_ENTITY}"
    rec.log(entity, rr.SeriesLines(names=[label], colors=[color], widths=[1.5]), static=True)
    if alignment.t_s.size == 0:
        return
    t_ns = np.round(alignment.t_s * 1e9).astype(np.int64)
    rec.send_columns(entity, indexes=[rr.TimeColumn(timeline, duration=t_ns.astype(
        "timedelta64[ns]"))], columns=rr.Scalars.columns(scalars=alignment.deviation_m))


def deviation_view(roots: Sequence[str], reference: str) -> rrb.TimeSeriesView:
    """The deviation panel of the runs under ``roots`` (their ``deviation`` entities)."""
    return rrb.TimeSeriesView(
        name=f"Distance to {reference} at the same time [m]", origin="/",
        contents=[f"{r}/{DEVIATION_ENTITY}/**" for r in roots],
        plot_legend=rrb.PlotLegend(visible=True, corner=rrb.Corner2D.LeftTop))


def alignment_lines(names: Sequence[str], alignments: Sequence[Alignment]) -> list[str]:
    """One line per aligned run: its shift, and the mean and largest deviation."""
    lines = []
    for a in alignments:
        dev = a.deviation_m
        span = (f"mean {float(np.mean(dev)):.3f} m, largest {float(np.max(dev)):.3f} m at "
                f"t = {float(a.t_s[int(np.argmax(dev))]):.2f} s" if dev.size
                else "no common time")
        lines.append(f"{names[a.run]} aligned to {names[a.reference]} at the start of motion "
                     f"(t = {a.start_s:.2f} s; its times shifted by {a.shift_s:+.3f} s): "
                     f"distance between the paths {span}")
    return lines


__all__ = ["DEVIATION_ENTITY", "Alignment", "align_runs", "alignment_lines", "deviation_view",
           "log_deviation"]

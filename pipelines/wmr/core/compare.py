"""Two runs of one manoeuvre on one time axis: a simulation against a real robot's log.

A simulation starts moving at t = 0; a real robot's log starts when its logger did, seconds
before the robot moved, on the wall clock.  The two are put on one axis by their **start of
motion**: the first time the pose is :data:`MOTION_THRESHOLD_M` from its first position, or
:data:`MOTION_THRESHOLD_RAD` from its first heading (a turn in place is motion too),
whichever comes first, interpolated linearly between the two samples either side of the
threshold (so the alignment does not depend on either log's sample times).  The thresholds
are above a localisation's jitter at rest (a few mm, a fraction of a degree) and below what a
robot covers in its first tenth of a second of motion.

The **deviation** between the two paths is then, at each sample time of the second run inside
the span of the first, the distance between their positions at that aligned time, the first's
interpolated linearly between its samples.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: The pose has moved once its position is this far from its first position, m.
MOTION_THRESHOLD_M: Final = 0.02
#: ... or its heading this far from its first heading, rad (2 degrees).
MOTION_THRESHOLD_RAD: Final = math.radians(2.0)


def _crossing_s(t_s: NDArray[np.float64], d: NDArray[np.float64], threshold: float
                ) -> float | None:
    """The first time ``d`` reaches ``threshold`` (``d[0]`` = 0), interpolated linearly."""
    hits = np.flatnonzero(d >= threshold)
    if hits.size == 0:
        return None
    i = int(hits[0])
    if i == 0:
        return float(t_s[0])
    d0, d1 = float(d[i - 1]), float(d[i])
    t0, t1 = float(t_s[i - 1]), float(t_s[i])
    return t0 + (threshold - d0) / (d1 - d0) * (t1 - t0)


def motion_start_s(t_s: ArrayLike, x_m: ArrayLike, y_m: ArrayLike, theta_rad: ArrayLike, *,
                   threshold_m: float = MOTION_THRESHOLD_M,
                   threshold_rad: float = MOTION_THRESHOLD_RAD) -> float | None:
    """The start of motion of a run: the first time its pose is ``threshold_m`` from its
    first position or ``threshold_rad`` from its first heading (unwrapped), interpolated
    between the samples either side; rows with a NaN are left out.

    Parameters
    ----------
    t_s
        Sample times, s, increasing.
    x_m, y_m, theta_rad
        The pose at each sample.

    Returns
    -------
    float or None
        The time, s; None when the pose never moves that far (or has no finite row).
    """
    t = np.asarray(t_s, np.float64)
    pose = np.column_stack([np.asarray(x_m, np.float64), np.asarray(y_m, np.float64),
                            np.asarray(theta_rad, np.float64)])
    ok = np.isfinite(pose).all(axis=1) & np.isfinite(t)
    t, pose = t[ok], pose[ok]
    if t.size == 0:
        return None
    moved = np.hypot(pose[:, 0] - pose[0, 0], pose[:, 1] - pose[0, 1])
    turned = np.abs(pose[:, 2] - pose[0, 2])
    starts = [s for s in (_crossing_s(t, moved, threshold_m),
                          _crossing_s(t, turned, threshold_rad)) if s is not None]
    return min(starts) if starts else None


def path_deviation_m(t_ref_s: ArrayLike, xy_ref_m: ArrayLike, t_s: ArrayLike, xy_m: ArrayLike
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Distance between two paths at the same time: at each time of ``t_s`` inside the span of
    ``t_ref_s``, from ``xy_m`` there to the reference interpolated linearly at that time.

    Parameters
    ----------
    t_ref_s, xy_ref_m
        The reference run: times (s, increasing) and positions ``(n, 2)``, m.
    t_s, xy_m
        The other run, on the same (aligned) time axis: times and positions ``(k, 2)``.

    Returns
    -------
    (times, distances)
        The times of ``t_s`` inside the reference's span (rows with a NaN left out), s,
        and the distance there, m.
    """
    tr = np.asarray(t_ref_s, np.float64)
    pr = np.asarray(xy_ref_m, np.float64).reshape(-1, 2)
    t = np.asarray(t_s, np.float64)
    p = np.asarray(xy_m, np.float64).reshape(-1, 2)
    ok_ref = np.isfinite(pr).all(axis=1) & np.isfinite(tr)
    tr, pr = tr[ok_ref], pr[ok_ref]
    ok = np.isfinite(p).all(axis=1) & np.isfinite(t)
    if tr.size:
        ok &= (t >= tr[0]) & (t <= tr[-1])
    else:
        ok[:] = False
    t, p = t[ok], p[ok]
    ref_x = np.interp(t, tr, pr[:, 0]) if t.size else np.zeros(0)
    ref_y = np.interp(t, tr, pr[:, 1]) if t.size else np.zeros(0)
    return t, np.hypot(p[:, 0] - ref_x, p[:, 1] - ref_y)


__all__ = ["MOTION_THRESHOLD_M", "MOTION_THRESHOLD_RAD", "motion_start_s", "path_deviation_m"]

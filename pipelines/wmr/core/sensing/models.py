"""Sensor models on the master's control grid: GPS-like position fixes, a compass, wheel
encoders.

Time is the control grid ``t_n = n h``.  A sensor of rate ``f`` samples at step ``n`` when
``floor(n h f)`` moves on (``n = 0`` included), so it takes ``f`` samples per second on average
with at most one per step (rates above the control rate are refused).  A sample measured at
step ``n`` arrives ``ceil(latency / h)`` steps later (latencies round up to the grid: a fix is
never early).  Every noise stream has its own :class:`numpy.random.Generator` (PCG64) spawned
from ``SeedSequence([seed, *trip])``, the trip being the bits of the start and goal poses
(:func:`trip_entropy`), so a run is reproducible bit for bit on any executor, switching one
sensor on or off leaves the draws of the others unchanged, and runs of the same trip that differ
only in controller, gains, limits or estimator see the same noise (common random numbers).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from wmr.core.sensing.config import SensorConfig

#: Independent noise streams, in spawn order (never reorder: it would change every draw).
STREAMS: Final = ("gps_noise", "gps_bias", "gps_dropout", "compass", "initial")
#: What seeds the streams (:func:`generators`), part of a batch run's id with sensors: change
#: it with the seeding, so that a rerun never takes runs done with other streams as done.
NOISE_SEEDING: Final = "seed+start+goal"


def trip_entropy(trip: Sequence[float]) -> list[int]:
    """The trip (start and goal pose: ``x_m, y_m, heading_rad`` each) as seed words: the
    IEEE-754 bits of each value, ``-0.0`` counted as ``0.0``.

    Bit-exact rather than rounded: two random starts never share a stream by rounding, and the
    same trip typed twice (or read back from a log's effective scenario) always does.
    """
    values = np.asarray(trip, dtype=np.float64) + 0.0  # -0.0 + 0.0 is +0.0
    return [int(w) for w in values.view(np.uint64)]


def generators(seed: int, trip: Sequence[float]) -> dict[str, np.random.Generator]:
    """One PCG64 generator per stream of :data:`STREAMS`, seeded by ``seed`` and the ``trip``
    (:func:`trip_entropy`).

    The run's name is deliberately not part of the seed: a variant run is named after its
    overrides (:mod:`wmr.config.naming`), and a comparison of gains, controllers or estimators on
    one trip must see one noise realisation.
    """
    children = np.random.SeedSequence([seed, *trip_entropy(trip)]).spawn(len(STREAMS))
    return {name: np.random.Generator(np.random.PCG64(ss))
            for name, ss in zip(STREAMS, children, strict=True)}


class Schedule:
    """Sample steps of a sensor of ``rate_hz`` on a grid of ``period_s``, and its delay."""

    def __init__(self, rate_hz: float, latency_s: float, period_s: float) -> None:
        self._per_step = rate_hz * period_s
        self.delay_steps = max(0, math.ceil(latency_s / period_s - 1e-9))

    def samples(self, n: int) -> bool:
        """Whether the sensor measures at step ``n``."""
        if n == 0:
            return True
        # the 1e-9 keeps exact ratios (10 Hz on 100 Hz) from flickering with rounding
        return math.floor(n * self._per_step + 1e-9) != math.floor((n - 1) * self._per_step
                                                                   + 1e-9)


@dataclass(frozen=True)
class Fix:
    """A measurement: taken at step ``step``, delivered at step ``arrival``."""

    step: int
    arrival: int
    value: tuple[float, ...]


class Gps:
    """Position fixes ``(x_m, y_m)``: truth + bias random walk + white noise, with dropouts."""

    def __init__(self, cfg: SensorConfig, period_s: float,
                 rngs: dict[str, np.random.Generator]) -> None:
        self.cfg = cfg
        self.schedule = Schedule(cfg.gps_rate_hz, cfg.gps_latency_s, period_s)
        self._h = period_s
        self._noise = rngs["gps_noise"]
        self._bias_rng = rngs["gps_bias"]
        self._drop = rngs["gps_dropout"]
        self.bias_m = np.zeros(2)
        self._last_step = 0
        self._queue: deque[Fix] = deque()

    def measure(self, n: int, x_m: float, y_m: float) -> None:
        """Take the step's sample (if scheduled) of the true position."""
        if not self.schedule.samples(n):
            return
        cfg = self.cfg
        dt = (n - self._last_step) * self._h
        self._last_step = n
        # every stream draws on every sample, dropped or not: a dropout changes nothing else
        noise = self._noise.normal(0.0, 1.0, 2) * cfg.gps_sigma_m
        walk = self._bias_rng.normal(0.0, 1.0, 2) * (cfg.gps_bias_walk_m_per_sqrt_s
                                                     * math.sqrt(dt))
        lost = self._drop.random() < cfg.gps_dropout_probability
        self.bias_m = self.bias_m + walk
        t = n * self._h
        if lost or any(t0 <= t <= t1 for t0, t1 in cfg.gps_dropout_windows):
            return
        z = (x_m + float(self.bias_m[0] + noise[0]), y_m + float(self.bias_m[1] + noise[1]))
        self._queue.append(Fix(n, n + self.schedule.delay_steps, z))

    def arrivals(self, n: int) -> list[Fix]:
        """The fixes delivered at step ``n``, oldest first."""
        out: list[Fix] = []
        while self._queue and self._queue[0].arrival <= n:
            out.append(self._queue.popleft())
        return out


class Compass:
    """Heading fixes ``(theta_rad,)``: truth + white noise, wrapped to [-pi, pi)."""

    def __init__(self, cfg: SensorConfig, period_s: float,
                 rngs: dict[str, np.random.Generator]) -> None:
        self.sigma_rad = math.radians(cfg.compass_sigma_deg)
        self.schedule = Schedule(cfg.compass_rate_hz, cfg.compass_latency_s, period_s)
        self._rng = rngs["compass"]
        self._queue: deque[Fix] = deque()

    def measure(self, n: int, theta_rad: float) -> None:
        """Take the step's sample (if scheduled) of the true heading."""
        if not self.schedule.samples(n):
            return
        z = theta_rad + float(self._rng.normal()) * self.sigma_rad
        if not -math.pi <= z < math.pi:  # wrap only when needed: an exact compass is exact
            z = (z + math.pi) % (2.0 * math.pi) - math.pi
        self._queue.append(Fix(n, n + self.schedule.delay_steps, (z,)))

    def arrivals(self, n: int) -> list[Fix]:
        """The fixes delivered at step ``n``, oldest first."""
        out: list[Fix] = []
        while self._queue and self._queue[0].arrival <= n:
            out.append(self._queue.popleft())
        return out


class Encoders:
    """Wheel angles as an incremental encoder counts them: ``floor(phi / q) q``, q = 2 pi / N."""

    def __init__(self, cfg: SensorConfig, period_s: float) -> None:
        n = int(cfg.encoder_counts_per_rev)
        self.quantum_rad = 2.0 * math.pi / n if n else 0.0
        self.schedule = Schedule(cfg.encoder_hz(period_s), 0.0, period_s)

    def read(self, phi_rad: float) -> float:
        """The angle the encoder reports for a true angle ``phi_rad``, rad."""
        q = self.quantum_rad
        return math.floor(phi_rad / q) * q if q else phi_rad


__all__ = ["NOISE_SEEDING", "STREAMS", "Compass", "Encoders", "Fix", "Gps", "Schedule",
           "generators", "trip_entropy"]

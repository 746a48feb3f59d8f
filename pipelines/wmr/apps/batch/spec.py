"""Batch spec files: a scenario plus the ways to vary it, expanded into identified runs.

A batch spec is a scenario file (:mod:`wmr.config.scenario`) with up to three more sections::

    name = "gains"                     # the scenario part: base run(s), as in any scenario
    start = [0.0, 0.0, 0.0]
    goal = [5.0, 2.0, 0.0]

    [grid]                             # cartesian product of lists ([sweep] is a synonym)
    max_time_s = [30.0, 60.0]
    start = [[0, 0, 0], [1, 0, 90]]    # whole poses, [x_m, y_m, heading_deg] ...
    [grid.goal]
    heading_deg = [-30.0, 0.0, 30.0]   # ... or pose components
    [grid.gains]
    K_ps = [0.3, 0.5, 0.8]

    [[list]]                           # explicit variants, one table each
    name = "heavy"
    params = { m = 40.0 }
    [[list]]
    name = "weak-motor"
    limits = { torque_max_nm = 4.0 }

    [random]                           # Monte Carlo samples
    seed = 1
    n = 100
    [random.params]
    m = { dist = "normal", mean = 25.0, std = 3.0, low = 15.0, high = 35.0 }
    l = { dist = "uniform", low = 0.25, high = 0.45 }
    [random.start]
    r_m = { dist = "uniform", low = 5.0, high = 12.0 }     # polar, about the goal
    bearing_deg = { dist = "uniform", low = 0.0, high = 360.0 }
    [random.goal]
    heading_deg = { dist = "along_x" }                      # the paper's Fig. 10 rule

Fields that can vary: ``gains.*``, ``limits.*``, ``params.*``, ``sensors.*`` (the fields of
:class:`~wmr.core.control.stabiliser.Gains`, :class:`~wmr.core.control.stabiliser.Limits`,
:class:`~wmr.core.plant.RobotParams` and :class:`~wmr.core.sensing.config.SensorConfig` but its
dropout
windows; ``sensors.estimator`` and ``sensors.heading`` take names in ``[grid]`` and ``[[list]]``,
and varying any sensor field of a run without ``[sensors]`` gives it the defaults for the rest),
``start`` and ``goal`` (whole poses, or the components
``x_m``, ``y_m``, ``heading_deg``; the start also ``r_m`` and ``bearing_deg``, its distance from
and bearing about the goal), ``max_time_s``, ``stop_radius_m``, ``control_period_s`` and
``heading_tolerance_deg``.

Distributions of ``[random]``: ``uniform`` (``low``, ``high``), ``normal`` (``mean``, ``std``,
optional ``low``/``high`` bounds: a truncated normal, by rejection), ``choice`` (``values``), and
for ``goal.heading_deg`` only ``along_x``: 0 deg when the start is left of the goal
(``x_start < x_goal``), 180 deg otherwise (Section 5, Fig. 10).  Sample ``i`` of field ``f`` is
drawn from a generator seeded by ``(seed, i, crc32(f))``: adding samples or fields keeps the
values drawn already.

The runs are every combination: base run x grid point x list entry x random sample (a missing
section counts as one empty variant), in that order (base run slowest).  Each gets a stable id
``NNNN-hhhhhhhh``: its index in that order and the first 8 hex digits of the SHA-256 of its
complete :class:`~wmr.core.runspec.RunSpec`.  Every error is a
:class:`~wmr.infra.errors.ConfigError` naming the field, e.g. ``random.params.m.std``.

Expansion is lazy (:class:`RunList`): the run count comes from the section sizes, and run ``i``
is made from ``i`` when it is needed, so a spec of a million runs loads in milliseconds and a
batch of it holds only the runs in flight.  Loading still checks what can be wrong: every run
of a spec of up to :data:`CHECK_ALL_RUNS` runs; for a larger one, every grid value, every list
entry and the first :data:`CHECK_SAMPLES` samples, with every base run.  A run found invalid
later (a sample drawn out of range) stops its batch with the same error, naming the run.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
import math
import operator
import zlib
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any, Final, overload

import numpy as np

from wmr.apps.run import LOG_KEEPS, LogPolicy
from wmr.config.scenario import (
    TOP_FIELDS,
    Overrides,
    parse_scenario,
    read_toml,
    resolve_scenario_path,
    unknown_field,
    with_overrides,
)
from wmr.core.control import registry
from wmr.core.control.stabiliser import Gains, Limits
from wmr.core.plant import Pose, RobotParams
from wmr.core.runspec import RunSpec
from wmr.core.sensing.config import NAME_FIELDS, SensorConfig
from wmr.core.sensing.models import NOISE_SEEDING
from wmr.infra.errors import ConfigError

#: ``optimal`` of a batch spec: the objectives a batch can solve beside every run
#: (:func:`wmr.apps.optimal.optimum_fields`; the OCP's own ``mix`` is not offered).
BATCH_OBJECTIVES: Final = ("time", "energy")

#: Sections a batch spec adds to a scenario file (``optimal`` is a top-level key: the
#: objective of the optimum solved beside every run).
BATCH_SECTIONS: Final = ("grid", "sweep", "list", "random", "log", "optimal")
#: Upper bound on the number of runs of one spec (a typo in a grid should not mean 10^9 runs).
MAX_RUNS: Final = 1_000_000
#: Pose columns every summary has, resolved from the run itself.
POSE_COLUMNS: Final = ("start.x_m", "start.y_m", "start.heading_deg",
                       "goal.x_m", "goal.y_m", "goal.heading_deg")
_GROUPS: Final[dict[str, tuple[str, ...]]] = {
    "gains": tuple(f.name for f in fields(Gains)),
    "limits": tuple(f.name for f in fields(Limits)),
    "params": tuple(f.name for f in fields(RobotParams)),
    "sensors": tuple(f.name for f in fields(SensorConfig) if f.name != "gps_dropout_windows"),
}
#: Summary columns that hold a name, not a number.
NAME_COLUMNS: Final = tuple(f"sensors.{k}" for k in NAME_FIELDS)
_POSE_PARTS: Final[dict[str, tuple[str, ...]]] = {
    "start": ("x_m", "y_m", "heading_deg", "r_m", "bearing_deg"),
    "goal": ("x_m", "y_m", "heading_deg"),
}
_SCALARS: Final = ("max_time_s", "stop_radius_m", "control_period_s", "heading_tolerance_deg")
#: The controller dimension (``[grid]`` and ``[[list]]`` only: a random draw is shared by every
#: controller, never drawn per controller).
CONTROLLER: Final = "controller"
CONTROLLER_GAINS: Final = "controller_gains"
_FIELDS: Final = (*_GROUPS, *_POSE_PARTS, *_SCALARS, CONTROLLER, CONTROLLER_GAINS)
_DISTS: Final[dict[str, tuple[tuple[str, ...], tuple[str, ...]]]] = {
    # name: (required keys, optional keys)
    "uniform": (("low", "high"), ()),
    "normal": (("mean", "std"), ("low", "high")),
    "choice": (("values",), ()),
    "along_x": ((), ()),
}
ALONG_X: Final = "along_x"

Value = float | str
"""A variant's value of one field: a number, or the name of a rule (``"along_x"``)."""


@dataclass(frozen=True)
class BatchRun:
    """One run of a batch.

    Attributes
    ----------
    run_id
        Stable id ``NNNN-hhhhhhhh`` (index, hash of the run's inputs).
    spec
        The complete run.
    base
        Name of the scenario run it derives from.
    variant
        Name of its ``[[list]]`` entry, ``""`` if none.
    inputs
        The varied fields as summary columns (``"params.m"``, ``"start.r_m"``, ...), plus the
        pose columns of :data:`POSE_COLUMNS`.
    draw
        Its random draw: the index of its ``[random]`` sample (0 without ``[random]``).  Runs
        of one draw have the same random inputs, whatever their controller, grid point or list
        entry (common random numbers).
    """

    run_id: str
    spec: RunSpec
    base: str
    variant: str
    inputs: dict[str, float | str]
    #: :func:`spec_digest` of ``spec`` (its first 8 hex digits end the id).
    digest: str
    draw: int = 0

    @property
    def name(self) -> str:
        """The run's name (``spec.name``)."""
        return self.spec.name

    @property
    def controller(self) -> str:
        """The run's controller (``spec.controller``)."""
        return self.spec.controller


@dataclass(frozen=True)
class BatchSpec:
    """A loaded batch spec.

    Attributes
    ----------
    name, description
        From the scenario part.
    runs
        Every run, in index order (sorted by id): a :class:`RunList`, which knows its length
        at once and makes each run when asked.
    input_columns
        Summary input columns: :data:`POSE_COLUMNS` then the varied fields in order of first
        appearance.
    path
        The file, if loaded from one.
    source
        The file's bytes (attached to each run's log), ``b""`` if none.
    """

    name: str
    description: str
    runs: Sequence[BatchRun]
    input_columns: tuple[str, ...]
    path: Path | None = None
    source: bytes = b""
    #: The scenario part's ``fmu`` and ``fmu_map`` (:mod:`wmr.adapters.fmi.varmap`), if given.
    fmu: Path | None = None
    fmu_map: Path | None = None
    #: The ``[log]`` table: which runs keep a log; ``None`` if the spec has none (the batch's
    #: size then decides, :func:`wmr.apps.batch.runner.default_log_policy`).
    log: LogPolicy | None = None
    #: The top-level ``optimal``: ``"time"`` or ``"energy"``, the OCP solved beside every run
    #: (:func:`wmr.apps.optimal.optimum_fields`); ``None``: none, and no optimum columns.
    optimal: str | None = None


@dataclass(frozen=True)
class _Dist:
    kind: str
    args: dict[str, Any]
    where: str

    def sample(self, rng: np.random.Generator) -> Value:
        a = self.args
        if self.kind == "uniform":
            return float(rng.uniform(a["low"], a["high"]))
        if self.kind == "choice":
            values: list[float] = a["values"]
            return values[int(rng.integers(len(values)))]
        if self.kind == ALONG_X:
            return ALONG_X
        low, high = a.get("low", -math.inf), a.get("high", math.inf)
        for _ in range(10_000):
            x = float(rng.normal(a["mean"], a["std"]))
            if low <= x <= high:
                return x
        raise ConfigError(self.where, f"no sample of normal({a['mean']:g}, {a['std']:g}) fell "
                          f"within [{low:g}, {high:g}] in 10000 draws",
                          "widen the bounds or move the mean inside them")


# -- parsing ---------------------------------------------------------------------------------

def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(where, f"must be a number, got {value!r}", "write a plain number")
    if not math.isfinite(value):
        raise ConfigError(where, f"must be finite, got {value!r}", "give a finite number")
    return float(value)


def _table(value: object, where: str, example: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ConfigError(where, f"must be a table, got {value!r}", f"write e.g. {example}")
    return value


def _unknown(where: str, allowed: Sequence[str]) -> ConfigError:
    return unknown_field(where, allowed)


def _value(field: str, value: object, where: str) -> Value:
    """A variant's value: a name for :data:`NAME_COLUMNS` and ``controller``, a number
    otherwise."""
    if field == CONTROLLER:
        known = registry.names()
        if value not in known:
            raise ConfigError(where, f"unknown controller {_cut(value)}",
                              f"use one of: {', '.join(known)}")
        registry.get(value, where)  # a plug-in is loaded here, its failure named at its field
        return str(value)
    if field in NAME_COLUMNS:
        if not isinstance(value, str):
            raise ConfigError(where, f"must be a name, got {value!r}", 'quote it, e.g. "ekf"')
        return value
    return _number(value, where)


def _pose_values(value: object, where: str, part: str) -> dict[str, float]:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise ConfigError(where, f"must be a pose [x_m, y_m, heading_deg], got {value!r}",
                          "write three numbers, e.g. [10.0, 0.0, 0.0]")
    return {f"{part}.{k}": _number(v, f"{where}.{k}")
            for k, v in zip(("x_m", "y_m", "heading_deg"), value, strict=True)}


def _leaves(table: Mapping[str, Any], where: str,
            skip: tuple[str, ...] = ()) -> list[tuple[str, str, object]]:
    """Walk a grid/list/random table: ``(field, source path, raw value)`` per leaf.

    A whole pose (``start = [...]``) is one leaf with field ``"start"``.
    """
    out: list[tuple[str, str, object]] = []
    for key, value in table.items():
        src = f"{where}.{key}"
        if key in skip:
            continue
        if key in _GROUPS:
            for name, v in _table(value, src, f"[{src}] with fields").items():
                if name not in _GROUPS[key]:
                    raise _unknown(f"{src}.{name}", _GROUPS[key])
                out.append((f"{key}.{name}", f"{src}.{name}", v))
        elif key in _POSE_PARTS:
            if isinstance(value, Mapping) and not ("dist" in value and where.startswith("random")):
                for name, v in value.items():
                    if name not in _POSE_PARTS[key]:
                        raise _unknown(f"{src}.{name}", _POSE_PARTS[key])
                    out.append((f"{key}.{name}", f"{src}.{name}", v))
            else:
                out.append((key, src, value))
        elif key in _SCALARS or key == CONTROLLER:
            out.append((key, src, value))
        elif key == CONTROLLER_GAINS:
            out.extend(_peer_gain_leaves(value, src))
        else:
            raise _unknown(src, (*skip, *_FIELDS))
    return out


def _peer_gain_leaves(value: object, where: str) -> list[tuple[str, str, object]]:
    """``controller_gains`` of a ``[grid]`` or ``[[list]]``: a table by controller name of its
    gains, each gain checked against the controller's declared ones (field
    ``controller_gains.<controller>.<gain>``)."""
    out: list[tuple[str, str, object]] = []
    # the controllers with gains of their own (a plug-in's always: only the PI's are [gains])
    own = tuple(n for n in registry.names() if n not in registry.BUILTIN_NAMES
                or registry.get(n).gains_table == CONTROLLER_GAINS)
    for name, gains in _table(value, where, f"[{where}.astolfi] with k_rho = ...").items():
        src = f"{where}.{name}"
        if name in registry.BUILTIN_NAMES and name not in own:
            raise ConfigError(src, f"the {name.upper()} takes its gains from [gains]",
                              f"vary them as gains.K_ps, ...; {where} is for {', '.join(own)}")
        if name not in registry.names():
            raise ConfigError(src, f"unknown controller {_cut(name)}",
                              f"give the gains of one of: {', '.join(own)}")
        known = tuple(g.name for g in registry.get(name, src).gains)
        example = f"[{src}] with {known[0]} = ..." if known else f"no [{src}]: it has no gains"
        for gain, raw in _table(gains, src, example).items():
            if gain not in known:
                raise ConfigError(f"{src}.{gain}", f"not a gain of {name}",
                                  f"{name}'s gains: {', '.join(known)}")
            out.append((f"{CONTROLLER_GAINS}.{name}.{gain}", f"{src}.{gain}", raw))
    return out


def _grid(table: Mapping[str, Any], where: str
          ) -> tuple[list[list[dict[str, Value]]], dict[str, str]]:
    """Grid axes (their cartesian product is the grid, first axis slowest) and the source of
    each field.  The product is left to the caller: it may be too large to build."""
    axes: list[list[dict[str, Value]]] = []
    sources: dict[str, str] = {}
    for field, src, raw in _leaves(table, where):
        if not isinstance(raw, list) or not raw:
            raise ConfigError(src, f"must be a non-empty list of values, got {raw!r}",
                              "write e.g. [0.3, 0.5, 0.8]")
        axis: list[dict[str, Value]]
        if field in _POSE_PARTS:
            axis = [dict(_pose_values(v, f"{src}[{i}]", field)) for i, v in enumerate(raw)]
            for k in axis[0]:
                sources[k] = src
        else:
            axis = [{field: _value(field, v, f"{src}[{i}]")} for i, v in enumerate(raw)]
            sources[field] = src
        axes.append(axis)
    return axes, sources


def _list(entries: object) -> tuple[list[tuple[str, dict[str, Value]]], dict[str, str]]:
    if not isinstance(entries, list) or not entries:
        raise ConfigError("list", "must be a non-empty array of tables",
                          "write [[list]] blocks, each with the fields it changes")
    out: list[tuple[str, dict[str, Value]]] = []
    sources: dict[str, str] = {}
    for i, entry in enumerate(entries):
        where = f"list[{i}]"
        table = _table(entry, where, "a [[list]] block")
        name = table.get("name", "")
        if not isinstance(name, str):
            raise ConfigError(f"{where}.name", f"must be a string, got {name!r}", "quote it")
        values: dict[str, Value] = {}
        for field, src, raw in _leaves(table, where, skip=("name",)):
            if field in _POSE_PARTS:
                values.update(_pose_values(raw, src, field))
                for k in ("x_m", "y_m", "heading_deg"):
                    sources.setdefault(f"{field}.{k}", f"{src}.{k}")
            else:
                values[field] = _value(field, raw, src)
                sources.setdefault(field, src)
        out.append((name, values))
    return out, sources


def _dist(raw: object, field: str, src: str) -> _Dist:
    table = _table(raw, src, '{ dist = "uniform", low = 0.0, high = 1.0 }')
    kind = table.get("dist")
    if kind not in _DISTS:
        raise ConfigError(f"{src}.dist", f"unknown distribution {kind!r}",
                          f"use one of: {', '.join(_DISTS)}")
    if kind == ALONG_X and field != "goal.heading_deg":
        raise ConfigError(f"{src}.dist", "'along_x' is a rule for goal.heading_deg only",
                          "use it under [random.goal] heading_deg")
    required, optional = _DISTS[kind]
    args: dict[str, Any] = {}
    for key, value in table.items():
        if key == "dist":
            continue
        if key not in required + optional:
            raise _unknown(f"{src}.{key}", ("dist", *required, *optional))
        if key == "values":
            if not isinstance(value, list) or not value:
                raise ConfigError(f"{src}.values", f"must be a non-empty list, got {value!r}",
                                  "write e.g. values = [1.0, 2.0]")
            args[key] = [_number(v, f"{src}.values[{i}]") for i, v in enumerate(value)]
        else:
            args[key] = _number(value, f"{src}.{key}")
    for key in required:
        if key not in args:
            raise ConfigError(f"{src}.{key}", "missing", f"a {kind} distribution needs "
                              f"{', '.join(required)}")
    if "std" in args and args["std"] <= 0.0:
        raise ConfigError(f"{src}.std", f"must be > 0, got {args['std']!r}",
                          "give a positive standard deviation")
    if "low" in args and "high" in args and not args["low"] < args["high"]:
        raise ConfigError(f"{src}.high", f"must be > low ({args['low']!r}), got {args['high']!r}",
                          "give low < high")
    return _Dist(kind, args, src)


def _random(table: Mapping[str, Any], max_runs: int = MAX_RUNS
            ) -> tuple[int, list[tuple[str, _Dist]], dict[str, str]]:
    """The sample count, the distributions and their sources (nothing drawn yet)."""
    seed = table.get("seed")
    if seed is None:
        raise ConfigError("random.seed", "missing (the samples must be reproducible)",
                          "write e.g. seed = 1")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError("random.seed", f"must be a non-negative integer, got {seed!r}",
                          "write e.g. seed = 1")
    n = table.get("n")
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= max_runs:
        raise ConfigError("random.n", f"must be an integer in [1, {max_runs}], got {_cut(n)}",
                          "write e.g. n = 100")
    for key in (CONTROLLER, CONTROLLER_GAINS):
        if key in table:
            # every controller must see the same draws (common random numbers)
            raise ConfigError(f"random.{key}", "is not drawn: each random draw is run under "
                              "every controller of the batch", f"vary {key} in [grid] or "
                              "[[list]]")
    dists: list[tuple[str, _Dist]] = []
    sources: dict[str, str] = {}
    for field, src, raw in _leaves(table, "random", skip=("seed", "n")):
        if field in _POSE_PARTS:
            raise ConfigError(src, "a random pose is drawn per component",
                              f"write [random.{field}] with x_m, y_m, heading_deg"
                              + (", r_m, bearing_deg" if field == "start" else ""))
        dists.append((field, _dist(raw, field, src)))
        sources[field] = src
    if not dists:
        raise ConfigError("random", "draws nothing", "add e.g. [random.params] with m = {...}")
    return n, dists, sources


def _log_policy(table: Mapping[str, Any]) -> LogPolicy:
    """The ``[log]`` table: ``keep`` (``full``, ``failed``, ``none``) and ``every_k_steps``."""
    for key in table:
        if key not in ("keep", "every_k_steps"):
            raise _unknown(f"log.{key}", ("keep", "every_k_steps"))
    keep = table.get("keep", "full")
    if keep not in LOG_KEEPS:
        raise ConfigError("log.keep", f"unknown policy {_cut(keep)}",
                          f"use one of: {', '.join(LOG_KEEPS)}")
    every = table.get("every_k_steps", 1)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ConfigError("log.every_k_steps", f"must be an integer >= 1, got {_cut(every)}",
                          "give e.g. every_k_steps = 10, or 1 for every step")
    return LogPolicy(keep, every)


def run_index(run_id: str) -> int | None:
    """The index a run id ``NNNN-hhhhhhhh`` starts with, ``None`` if it is not a run id."""
    head, dash, _ = run_id.partition("-")
    return int(head) if dash and head.isdigit() else None


def _sample(seed: int, i: int, dists: Sequence[tuple[str, _Dist]]) -> dict[str, Value]:
    """Sample ``i``: field ``f`` drawn from a generator seeded by ``(seed, i, crc32(f))``."""
    return {field: d.sample(np.random.default_rng([seed, i, zlib.crc32(field.encode())]))
            for field, d in dists}


def _cut(value: object, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters: error lines stay lines."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


# -- expansion -------------------------------------------------------------------------------

def _resolve(base: RunSpec, values: Mapping[str, Value], name: str) -> RunSpec:
    """``base`` with a variant's values applied."""
    def num(key: str) -> float:
        return float(values[key])

    goal = base.goal
    gx = num("goal.x_m") if "goal.x_m" in values else goal.x_m
    gy = num("goal.y_m") if "goal.y_m" in values else goal.y_m
    start = base.start
    sx, sy, sh = start.x_m, start.y_m, start.heading_rad
    polar = [k for k in ("start.r_m", "start.bearing_deg") if k in values]
    if polar:
        clash = [k for k in ("start.x_m", "start.y_m") if k in values]
        if clash:
            raise ConfigError(polar[0], f"conflicts with {clash[0]}",
                              "give the start either as x_m/y_m or as r_m/bearing_deg")
        r0 = math.hypot(sx - gx, sy - gy)
        b0 = math.atan2(sy - gy, sx - gx)
        r = num("start.r_m") if "start.r_m" in values else r0
        if r < 0.0:
            raise ConfigError("start.r_m", f"must be >= 0, got {r!r}", "give a distance")
        b = math.radians(num("start.bearing_deg")) if "start.bearing_deg" in values else b0
        sx, sy = gx + r * math.cos(b), gy + r * math.sin(b)
    sx = num("start.x_m") if "start.x_m" in values else sx
    sy = num("start.y_m") if "start.y_m" in values else sy
    if "start.heading_deg" in values:
        sh = math.radians(num("start.heading_deg"))
    gh = goal.heading_rad
    rule = values.get("goal.heading_deg")
    if rule == ALONG_X:
        gh = 0.0 if sx < gx else math.pi
    elif rule is not None:
        gh = math.radians(float(rule))

    def group(prefix: str) -> dict[str, float]:
        return {k[len(prefix) + 1:]: float(v) for k, v in values.items()
                if k.startswith(prefix + ".")}

    sensors = {k[len("sensors."):]: v for k, v in values.items() if k.startswith("sensors.")}

    def opt(key: str) -> float | None:
        return num(key) if key in values else None

    controller = str(values.get(CONTROLLER, base.controller))
    if controller != "pi" and base.controller_fmu is not None:
        raise ConfigError(CONTROLLER, f"the controller FMU is the PI stabiliser, but "
                          f"controller = {controller!r}", "drop controller_fmu or vary only pi")
    return with_overrides(base, Overrides(
        start=Pose(sx, sy, sh), goal=Pose(gx, gy, gh), name=name,
        gains=group("gains"), limits=group("limits"), params=group("params"),
        period_s=opt("control_period_s"), stop_radius_m=opt("stop_radius_m"),
        max_time_s=opt("max_time_s"), heading_tolerance_deg=opt("heading_tolerance_deg"),
        sensors=sensors, controller=controller,
        # the gains of the run's own controller; those given for another are not its own
        controller_gains=group(f"{CONTROLLER_GAINS}.{controller}")))


def _canonical(value: Any) -> Any:
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, dict):
        return {k: _canonical(v) for k, v in value.items()}
    return value


_FIELD_NAMES: dict[type, tuple[str, ...]] = {}


_PLAIN: Final = (float, int, str, bool, type(None))


def _flat(value: Any) -> Any:
    """:func:`dataclasses.asdict` without its deep copies (same result, a few times faster)."""
    if type(value) in _PLAIN:
        return value
    names = _FIELD_NAMES.get(type(value))
    if names is None:
        if not is_dataclass(value):
            if isinstance(value, tuple | list):
                return [_flat(v) for v in value]
            return value
        names = _FIELD_NAMES[type(value)] = tuple(f.name for f in fields(value))
    return {name: _flat(getattr(value, name)) for name in names}


def spec_digest(spec: RunSpec) -> str:
    """SHA-256 of a run's complete inputs (floats by ``repr``: bit-exact)."""
    d = _flat(spec)
    # runs without sensors or a controller FMU keep the ids they had before those keys
    for key in ("sensors", "controller_fmu"):
        if d[key] is None:
            del d[key]
    if spec.sensors is not None:
        # the noise is seeded by the trip, no longer by the run's name: a rerun must not skip
        # runs journalled with the earlier streams as done
        d["noise_seeding"] = NOISE_SEEDING
    text = json.dumps(_canonical(d), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _inputs(spec: RunSpec, values: Mapping[str, Value], columns: Sequence[str]
            ) -> dict[str, float | str]:
    row: dict[str, float | str] = {
        "start.x_m": spec.start.x_m, "start.y_m": spec.start.y_m,
        "start.heading_deg": math.degrees(spec.start.heading_rad),
        "goal.x_m": spec.goal.x_m, "goal.y_m": spec.goal.y_m,
        "goal.heading_deg": math.degrees(spec.goal.heading_rad),
    }
    actual: dict[str, float | str] = {
        "max_time_s": spec.t_max_s, "stop_radius_m": spec.stop_radius_m,
        "control_period_s": spec.period_s,
        "heading_tolerance_deg": math.degrees(spec.heading_tolerance_rad),
    }
    for group, obj in (("gains", spec.gains), ("limits", spec.limits), ("params", spec.params)):
        actual.update({f"{group}.{k}": v for k, v in _flat(obj).items()})
    if spec.sensors is not None:
        actual.update({f"sensors.{k}": v for k, v in spec.sensors.as_dict().items()
                       if k in _GROUPS["sensors"]})
    # every gain the run's controller uses, its defaults included (none of its own: the PI)
    actual.update({f"{CONTROLLER_GAINS}.{spec.controller}.{k}": v for k, v in
                   registry.check_gains(spec.controller, dict(spec.controller_gains)).items()})
    for col in columns:
        if col in row:
            continue
        if col in actual:
            v = actual[col]
            row[col] = v if isinstance(v, str) else float(v)
        elif col.startswith(f"{CONTROLLER_GAINS}."):  # another controller's gain: not this run's
            row[col] = math.nan
        else:  # start.r_m, start.bearing_deg: as drawn, NaN where not given
            drawn = values.get(col)
            row[col] = float(drawn) if isinstance(drawn, int | float) else math.nan
    return row


#: A spec of at most this many runs has every run checked when it is loaded; a larger one has
#: its probes checked (:meth:`RunList.probes`) and the rest as they are made.
CHECK_ALL_RUNS: Final = 1000
#: Random samples checked at load, with each base run.
CHECK_SAMPLES: Final = 100


class RunList(Sequence[BatchRun]):
    """The runs of a spec, made on demand.

    Its length is the product of the section sizes, known at once; run ``i`` is made from
    ``i`` alone when it is asked for (mixed radix: base slowest, then each grid axis in order,
    the list entry, the random sample fastest), so a batch of a million runs starts at once
    and holds in memory only the runs it is running.

    Raises
    ------
    ConfigError
        When a run made is invalid (a value out of range, e.g. a drawn negative mass): the
        field, its source in the spec, and the run's index and name.
    """

    def __init__(self, bases: Sequence[RunSpec], axes: Sequence[Sequence[dict[str, Value]]],
                 entries: Sequence[tuple[str, dict[str, Value]]], seed: int, n_samples: int,
                 dists: Sequence[tuple[str, _Dist]], columns: Sequence[str],
                 sources: Mapping[str, str]) -> None:
        self._bases = tuple(bases)
        self._axes = tuple(tuple(a) for a in axes)
        self._entries = tuple(entries)
        self._n_samples = n_samples
        self._dists = tuple(dists)
        self._columns = tuple(columns)
        self._sources = dict(sources)
        self._n_points = math.prod(len(a) for a in self._axes)
        self._n_variants = self._n_points * len(self._entries) * n_samples
        self._total = len(self._bases) * self._n_variants
        self._width = max(4, len(str(self._total - 1)))
        self._seed = seed
        self._cache()

    def _cache(self) -> None:
        # a grid sweeps its samples once per point: keep them (a few kB each) while they last
        self._draw = functools.lru_cache(maxsize=4096)(
            functools.partial(_sample, self._seed, dists=self._dists))

    def __getstate__(self) -> dict[str, Any]:
        # a batch's workers draw their runs themselves: the list goes to them (a few kB,
        # its bases, axes and distributions), its cache of samples does not
        state = dict(self.__dict__)
        del state["_draw"]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._cache()

    def head(self, n_runs: int) -> RunList:
        """The first ``n_runs`` runs, as a list made on demand: the same runs, ids and names
        (their width is the whole list's)."""
        first = copy.copy(self)
        first._total = max(0, min(n_runs, self._total))
        return first

    def __len__(self) -> int:
        return self._total

    @overload
    def __getitem__(self, index: int) -> BatchRun: ...

    @overload
    def __getitem__(self, index: slice) -> list[BatchRun]: ...

    def __getitem__(self, index: int | slice) -> BatchRun | list[BatchRun]:
        if isinstance(index, slice):
            return [self._make(i) for i in range(*index.indices(self._total))]
        i = operator.index(index)
        if i < 0:
            i += self._total
        if not 0 <= i < self._total:
            raise IndexError(f"run {index} of {self._total}")
        return self._make(i)

    def __iter__(self) -> Iterator[BatchRun]:
        for i in range(self._total):
            yield self._make(i)

    def probes(self) -> list[int]:
        """Indices that together try every grid value, every list entry and the first
        :data:`CHECK_SAMPLES` samples with every base run (each with the first of the rest)."""
        s, e = self._n_samples, len(self._entries)
        variants: set[int] = set()
        stride = e * s
        for k in reversed(range(len(self._axes))):
            variants.update(j * stride for j in range(len(self._axes[k])))
            stride *= len(self._axes[k])
        variants.update(j * s for j in range(e))
        variants.update(range(min(s, CHECK_SAMPLES)))
        return sorted(b * self._n_variants + v for b in range(len(self._bases))
                      for v in variants)

    def check(self) -> None:
        """Make every run of a small spec, the :meth:`probes` of a large one: what is wrong
        with a spec is said when it is loaded, not hours into its batch."""
        for i in range(self._total) if self._total <= CHECK_ALL_RUNS else self.probes():
            self._make(i)

    def _fixed(self, i: int) -> tuple[int, str, dict[str, Value], int]:
        """Run ``i``'s base index, list entry name, fixed values (grid point, then list entry)
        and draw (its sample's index): what it is made of, nothing drawn yet."""
        i, k_sample = divmod(i, self._n_samples)
        i, k_entry = divmod(i, len(self._entries))
        k_base, k_point = divmod(i, self._n_points)
        values: dict[str, Value] = {}
        picks = []
        for axis in reversed(self._axes):
            k_point, k = divmod(k_point, len(axis))
            picks.append(axis[k])
        for pick in reversed(picks):  # the first axis first, as the spec lists them
            values.update(pick)
        variant, entry = self._entries[k_entry]
        values.update(entry)
        return k_base, variant, values, k_sample

    def _values(self, i: int) -> tuple[int, str, dict[str, Value], int]:
        """Run ``i``'s base index, list entry name, values (grid, entry, sample) and draw."""
        k_base, variant, values, k_sample = self._fixed(i)
        if self._dists:
            # drawn from the sample's index alone: the same draw under every controller, grid
            # point and list entry (common random numbers)
            values.update(self._draw(k_sample))
        return k_base, variant, values, k_sample

    def label(self, index: int) -> tuple[str, int]:
        """Run ``index``'s controller and draw, without making the run (a summary read back
        from the journal has its rows but not its runs)."""
        k_base, _, values, draw = self._fixed(operator.index(index))
        return str(values.get(CONTROLLER, self._bases[k_base].controller)), draw

    def _make(self, index: int) -> BatchRun:
        k_base, variant, values, draw = self._values(index)
        base = self._bases[k_base]
        label = base.name + (f"-{variant}" if variant else "")
        controller = str(values.get(CONTROLLER, base.controller))
        if CONTROLLER in self._sources and variant != controller:
            label += f"-{controller}"  # the controller varies: every name says which
        name = label if self._n_variants == 1 else f"{label}-{index:0{self._width}d}"
        try:
            spec = _resolve(base, values, name)
        except ConfigError as exc:
            field = self._source(exc.field, controller)
            raise ConfigError(field, f"{exc.problem} (run {index}, {name})", exc.fix) from None
        digest = spec_digest(spec)
        return BatchRun(run_id=f"{index:0{self._width}d}-{digest[:8]}", spec=spec,
                        base=base.name, variant=variant,
                        inputs=_inputs(spec, values, self._columns), digest=digest, draw=draw)

    def _source(self, field: str, controller: str) -> str:
        """Where in the spec the value of ``field`` came from (``field`` itself if from the
        scenario part); a peer's gain (``controller_gains.k_rho``) is looked up under the run's
        controller."""
        if field.startswith(f"{CONTROLLER_GAINS}.") or field == CONTROLLER_GAINS:
            peer = f"{CONTROLLER_GAINS}.{controller}{field[len(CONTROLLER_GAINS):]}"
            found = self._sources.get(peer) or next(
                (src.rpartition(".")[0] for key, src in self._sources.items()
                 if key.startswith(f"{CONTROLLER_GAINS}.{controller}.")), None)
            if found is not None:
                return found
        return self._sources.get(field, field)


def _check_peer_gains_used(bases: Sequence[RunSpec], axes: Sequence[Sequence[dict[str, Value]]],
                           entries: Sequence[tuple[str, dict[str, Value]]],
                           sources: Mapping[str, str]) -> None:
    """Refuse gains given for a controller that no run uses (a typo in the controller's name
    would otherwise run every run with its default gains, silently)."""
    used = {b.controller for b in bases}
    for values in (*(v for axis in axes for v in axis), *(v for _, v in entries)):
        if CONTROLLER in values:
            used.add(str(values[CONTROLLER]))
    gridded = {str(v[CONTROLLER]) for axis in axes for v in axis if CONTROLLER in v}
    for axis in axes:
        for key in axis[0]:
            name = key.split(".")[1] if key.startswith(f"{CONTROLLER_GAINS}.") else None
            if name is not None and gridded - {name}:
                # the other controllers' runs would be repeated once per value, unchanged
                raise ConfigError(sources[key], f"a grid of {name}'s gains beside a grid of "
                                  f"controllers ({', '.join(sorted(gridded))}) repeats every "
                                  f"run of the others once per value", f"give {name}'s gains "
                                  f"in a [[list]] entry with controller = {name!r}, or grid "
                                  f"them in a spec of {name} alone")
    for key, src in sources.items():
        if key.startswith(f"{CONTROLLER_GAINS}."):
            name = key.split(".")[1]
            if name not in used:
                raise ConfigError(src.rpartition(".")[0], f"gains of {name}, which no run uses "
                                  f"(the runs' controllers: {', '.join(sorted(used))})",
                                  f"add {name!r} to the controllers (controller = [...]) or "
                                  "drop the table")


def parse_batch(data: Mapping[str, Any], source: str = "<batch>", path: Path | None = None,
                raw: bytes = b"", max_runs: int = MAX_RUNS) -> BatchSpec:
    """Validate a batch spec's parsed TOML ``data`` and expand it into runs.

    Parameters
    ----------
    data
        The parsed TOML.
    source
        File name, for the default scenario name.
    path, raw
        The file and its bytes, kept for the logs' attachments.
    max_runs
        Refuse a spec of more runs than this (counted before anything is expanded).

    Raises
    ------
    ConfigError
        Naming the bad field.
    """
    for key in data:  # here, not in parse_scenario: a spec's sections are allowed fields too
        if key not in TOP_FIELDS and key not in BATCH_SECTIONS:
            raise unknown_field(key, (*TOP_FIELDS, *BATCH_SECTIONS))
    sections = {k: data[k] for k in BATCH_SECTIONS if k in data}
    scenario = parse_scenario({k: v for k, v in data.items() if k not in BATCH_SECTIONS},
                              source=source, path=path)
    sources: dict[str, str] = {}
    axes: list[list[dict[str, Value]]] = []
    if "grid" in sections and "sweep" in sections:
        raise ConfigError("sweep", "given together with [grid], its synonym",
                          "merge the two tables into one [grid]")
    for key in ("grid", "sweep"):
        if key in sections:
            axes, src = _grid(_table(sections[key], key, f"[{key}] with lists"), key)
            sources.update(src)
    entries: list[tuple[str, dict[str, Value]]] = [("", {})]
    if "list" in sections:
        entries, src = _list(sections["list"])
        for k, v in src.items():
            sources.setdefault(k, v)
    n_samples, dists = 1, list[tuple[str, _Dist]]()
    if "random" in sections:
        n_samples, dists, src = _random(_table(sections["random"], "random",
                                               "[random] with seed, n"), max_runs)
        for k, v in src.items():
            sources.setdefault(k, v)
    # counted from the sizes, before anything is expanded: a typo must not eat the memory
    n_points = math.prod(len(axis) for axis in axes)
    total = len(scenario.runs) * n_points * len(entries) * n_samples
    if total > max_runs:
        raise ConfigError("grid" if n_points > 1 else "random.n",
                          f"the spec expands to {total} runs, more than {max_runs}",
                          "use fewer values, or raise the limit with --max-runs")
    _check_peer_gains_used(scenario.runs, axes, entries, sources)
    columns = list(POSE_COLUMNS)
    for key in sources:
        if key not in columns and key != CONTROLLER:  # the summary's own column (summary.py)
            columns.append(key)
    seed = sections["random"]["seed"] if dists else 0
    log = _log_policy(_table(sections["log"], "log", '[log] with keep = "failed"')) \
        if "log" in sections else None
    optimal = sections.get("optimal")
    if optimal is not None and optimal not in BATCH_OBJECTIVES:
        raise ConfigError("optimal", f"unknown objective {_cut(optimal)}",
                          f"write optimal = {' or '.join(map(repr, BATCH_OBJECTIVES))}, or drop "
                          "it for no optimum")
    runs = RunList(scenario.runs, axes, entries, seed, n_samples, dists, columns, sources)
    runs.check()
    return BatchSpec(name=scenario.name, description=scenario.description, runs=runs,
                     input_columns=tuple(columns), path=path, source=raw,
                     fmu=scenario.fmu, fmu_map=scenario.fmu_map, log=log, optimal=optimal)


def load_batch(name_or_path: str | Path, max_runs: int = MAX_RUNS) -> BatchSpec:
    """Read, validate and expand a batch spec (or a plain scenario) file.

    Raises
    ------
    ConfigError
        The file is missing or not TOML (field ``spec``), or a field is bad (named).
    """
    path = resolve_scenario_path(name_or_path)
    data, raw = read_toml(path, "spec")
    return parse_batch(data, source=str(path), path=path, raw=raw, max_runs=max_runs)


__all__ = ["BatchRun", "BatchSpec", "RunList", "load_batch", "parse_batch", "run_index",
           "spec_digest"]

"""Scenario files (TOML): what to run, validated, expanded into :class:`RunSpec` s.

A scenario file::

    name = "fig11"
    description = "Fig. 11: (0, 0, 0 deg) to (20, 10, 0 deg)"
    start = [0.0, 0.0, 0.0]          # x_m, y_m, heading_deg
    goal = [20.0, 10.0, 0.0]         # x_m, y_m, heading_deg
    control_period_s = 0.01          # default 0.01
    stop_radius_m = 0.05             # epsilon of Section 4, default 0.05
    heading_tolerance_deg = 0.5      # final alignment tolerance, default 0.5
    max_time_s = 120.0               # default 120
    controller = "pi"                # pi (default), astolfi, graceful, a plug-in (docs/plugins.md)
    fmu = "other_robot.fmu"          # optional: drive this robot FMU (path relative to here)
    fmu_map = "other_robot.toml"     # optional: its variable map (docs/fmu_map.md)
    controller_fmu = true            # run the PI law in the controller FMU (or a path to one)

    [controller_gains]               # the controller's own gains (astolfi: k_rho, k_alpha, ...)
    k_rho = 3.0

    [gains]                          # any of wmr.core.control.Gains
    K_ps = 0.5
    [limits]                         # any of wmr.core.control.Limits
    torque_max_nm = 8.0
    [params]                         # any of wmr.core.plant.RobotParams
    m = 25.0

    [sensors]                        # optional: noisy, late fixes instead of the true state
    estimator = "ekf"                # (wmr.core.sensing.config; absent: perfect state feedback)
    gps_sigma_m = 0.02

    [[runs]]                         # optional: a set of runs (Figs. 9 and 10); each may
    name = "theta_d=+30"             # give name, start, goal, max_time_s, and inherits
    goal = [20.0, 10.0, 30.0]        # the top-level start and goal otherwise

Every error is a :class:`~wmr.infra.errors.ConfigError` that names the field.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from wmr.core.control.registry import check_gains
from wmr.core.control.stabiliser import Gains, Limits
from wmr.core.plant import Pose, RobotParams
from wmr.core.runspec import (
    DEFAULT_HEADING_TOLERANCE_DEG,
    DEFAULT_MAX_TIME_S,
    DEFAULT_PERIOD_S,
    DEFAULT_STOP_RADIUS_M,
    RunSpec,
    check_finite,
    check_positive,
)
from wmr.core.sensing.config import SensorConfig, override_sensors, sensor_config
from wmr.infra.errors import ConfigError
from wmr.infra.inputs import MAX_TOML_BYTES, read_input
from wmr.infra.paths import scenarios_dir

DEFAULT_SCENARIO = "fig11"

TOP_FIELDS = ("name", "description", "start", "goal", "runs", "gains", "limits", "params",
              "control_period_s", "stop_radius_m", "heading_tolerance_deg", "max_time_s",
              "controller", "controller_gains", "controller_fmu", "sensors", "fmu", "fmu_map")
RUN_FIELDS = ("name", "start", "goal", "max_time_s")


@dataclass(frozen=True)
class Scenario:
    """A loaded scenario file: its runs, already expanded."""

    name: str
    description: str
    runs: tuple[RunSpec, ...]
    path: Path | None = None
    #: The robot FMU to drive and its variable map (:mod:`wmr.adapters.fmi.varmap`); ``None``: the
    #: project's own FMU, our names.
    fmu: Path | None = None
    fmu_map: Path | None = None


def unknown_field(field: str, allowed: Sequence[str]) -> ConfigError:
    """The error of an unknown ``field`` (dotted): every allowed name, and the closest of them
    first when one is near (a misspelling such as ``[randm]`` or ``[[lists]]``).

    Parameters
    ----------
    field
        The unknown field's dotted path; its last part is what the user wrote.
    allowed
        Every name allowed where it stands.
    """
    near = difflib.get_close_matches(field.rsplit(".", 1)[-1], list(allowed), n=1)
    hint = f"did you mean {near[0]!r}? " if near else ""
    return ConfigError(field, "unknown field", f"{hint}allowed fields: {', '.join(allowed)}")


def _check_keys(table: Mapping[str, Any], allowed: Sequence[str], where: str) -> None:
    for key in table:
        if key not in allowed:
            raise unknown_field(f"{where}.{key}" if where else key, allowed)


#: A heading in degrees closer than this to a multiple of pi/12 rad looks like radians.
RADIANS_LOOKALIKE_TOL: float = 1e-3


def heading_looks_like_radians(heading_deg: float) -> str | None:
    """``"pi/2"``-style text when a heading given in degrees looks like one in radians, else
    ``None`` (headings are given in degrees; ``--goal 5 5 1.5708`` means 1.57 deg).

    The rule: a non-zero ``|heading_deg| <= 2 pi`` within :data:`RADIANS_LOOKALIKE_TOL` of a
    multiple of pi/12 (15 deg: 0.2618, 0.5236, 0.7854, 1.0472, 1.5708, 3.1416, ...).  No
    whole number is that close to one (the nearest, 6 and 22 pi/12 = 5.760, are 0.02 apart),
    so ordinary degree values (0, 1, 5, 30, 90) never trip it, nor does any heading above
    2 pi.
    """
    from fractions import Fraction

    value = abs(heading_deg)
    if value == 0.0 or value > 2.0 * math.pi + RADIANS_LOOKALIKE_TOL:
        return None
    k = round(value / (math.pi / 12.0))
    if k == 0 or abs(value - k * math.pi / 12.0) > RADIANS_LOOKALIKE_TOL:
        return None
    frac = Fraction(k, 12)
    text = ("" if frac.numerator == 1 else str(frac.numerator)) + "pi" \
        + ("" if frac.denominator == 1 else f"/{frac.denominator}")
    return ("-" if heading_deg < 0 else "") + text


def _pose(value: object, field: str) -> Pose:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise ConfigError(field, f"must be [x_m, y_m, heading_deg], got {value!r}",
                          "write three numbers, e.g. [20.0, 10.0, 0.0]")
    x = check_finite(f"{field}.x_m", value[0])
    y = check_finite(f"{field}.y_m", value[1])
    h = check_finite(f"{field}.heading_deg", value[2])
    return Pose(x, y, math.radians(h))


def _table(data: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, Mapping):
        raise ConfigError(key, f"must be a table, got {value!r}", f"write [{key}] with fields")
    return value


def _build(cls: type[Any], values: Mapping[str, Any], section: str, base: Any = None) -> Any:
    allowed = tuple(f.name for f in fields(cls))
    _check_keys(values, allowed, section)
    checked = {k: check_finite(f"{section}.{k}", v) for k, v in values.items()}
    try:
        return cls(**checked) if base is None else replace(base, **checked)
    except ConfigError as exc:
        if exc.fix:
            raise
        raise ConfigError(exc.field, exc.problem, "give a value within the bound") from None


def _peer_gains(controller: str, values: Mapping[str, Any]) -> tuple[tuple[str, float], ...]:
    """Validated ``controller_gains`` of ``controller`` as ``(name, value)`` pairs."""
    out: list[tuple[str, float]] = []
    for k, v in values.items():
        out.append((k, float(v) if isinstance(v, bool)
                    else check_finite(f"controller_gains.{k}", v)))
    check_gains(controller, dict(out))
    return tuple(out)


#: Tables of a batch spec (docs/batch.md) that a scenario file does not have.
BATCH_TABLES = ("grid", "list", "random", "sweep")


def _controller_fmu(value: object, path: Path | None) -> str | None:
    """``controller_fmu``: true (the built FMU, ``""``), false (``None``) or a path; a relative
    path is read from the scenario file's folder."""
    if isinstance(value, bool):
        return "" if value else None
    if not isinstance(value, str) or not value:
        raise ConfigError("controller_fmu", f"must be true, false or a path, got {value!r}",
                          'write controller_fmu = true or controller_fmu = "FILE.fmu"')
    fmu = Path(value)
    if not fmu.is_absolute() and path is not None:
        fmu = path.parent / fmu
    return str(fmu)


def parse_scenario(data: Mapping[str, Any], source: str = "<scenario>",
                   path: Path | None = None) -> Scenario:
    """Validate a scenario's parsed TOML ``data`` and expand it into runs."""
    for key in BATCH_TABLES:
        if key in data:
            raise ConfigError(key, f"{source} is a batch spec (it has [{key}]), not a scenario",
                              f"run it with 'wmr batch {source}'")
    _check_keys(data, TOP_FIELDS, "")
    name = data.get("name", Path(source).stem)
    if not isinstance(name, str) or not name:
        raise ConfigError("name", f"must be a non-empty string, got {name!r}",
                          'write e.g. name = "fig11"')
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError("description", f"must be a string, got {description!r}",
                          "quote the text")
    gains = _build(Gains, _table(data, "gains"), "gains")
    limits = _build(Limits, _table(data, "limits"), "limits")
    params = _build(RobotParams, _table(data, "params"), "params")
    period = check_positive("control_period_s", data.get("control_period_s", DEFAULT_PERIOD_S))
    eps = check_positive("stop_radius_m", data.get("stop_radius_m", DEFAULT_STOP_RADIUS_M))
    tol = check_positive("heading_tolerance_deg",
                    data.get("heading_tolerance_deg", DEFAULT_HEADING_TOLERANCE_DEG))
    t_max = check_positive("max_time_s", data.get("max_time_s", DEFAULT_MAX_TIME_S))
    controller = data.get("controller", "pi")
    if not isinstance(controller, str):
        raise ConfigError("controller", f"must be a string, got {controller!r}",
                          'write e.g. controller = "astolfi"')
    peer_gains = _peer_gains(controller, _table(data, "controller_gains"))
    controller_fmu = _controller_fmu(data.get("controller_fmu", False), path)
    if controller_fmu is not None and controller != "pi":
        raise ConfigError("controller_fmu", f"the controller FMU is the PI stabiliser, but "
                          f"controller = {controller!r}", "drop controller_fmu or use pi")
    sensors = sensor_config(_table(data, "sensors")) if "sensors" in data else None
    start = _pose(data["start"], "start") if "start" in data else None
    goal = _pose(data["goal"], "goal") if "goal" in data else None

    raw_runs = data.get("runs")
    if raw_runs is None:
        raw_runs = [{}]
    elif not isinstance(raw_runs, list) or not raw_runs:
        raise ConfigError("runs", "must be a non-empty array of tables",
                          'write [[runs]] blocks, each with start and/or goal')
    runs: list[RunSpec] = []
    # each name's index: the duplicate check is one lookup, not a scan of the earlier runs
    # (200,000 [[runs]] took minutes)
    index_of: dict[str, int] = {}
    for i, run in enumerate(raw_runs):
        where = f"runs[{i}]"
        if not isinstance(run, Mapping):
            raise ConfigError(where, f"must be a table, got {run!r}", "write a [[runs]] block")
        _check_keys(run, RUN_FIELDS, where)
        run_start = _pose(run["start"], f"{where}.start") if "start" in run else start
        run_goal = _pose(run["goal"], f"{where}.goal") if "goal" in run else goal
        if run_start is None:
            raise ConfigError("start" if raw_runs == [{}] else f"{where}.start", "missing",
                              "give start = [x_m, y_m, heading_deg]")
        if run_goal is None:
            raise ConfigError("goal" if raw_runs == [{}] else f"{where}.goal", "missing",
                              "give goal = [x_m, y_m, heading_deg]")
        run_name = run.get("name", name if len(raw_runs) == 1 else f"{name}-{i:02d}")
        if not isinstance(run_name, str) or not run_name:
            raise ConfigError(f"{where}.name", f"must be a non-empty string, got {run_name!r}",
                              "quote the name")
        earlier = index_of.setdefault(run_name, i)
        if earlier != i:
            raise ConfigError(f"{where}.name", f"{run_name!r} is already the name of "
                              f"runs[{earlier}]: the second could not be picked with --run",
                              "give each run its own name")
        run_t_max = check_positive(f"{where}.max_time_s", run.get("max_time_s", t_max))
        runs.append(RunSpec(name=run_name, start=run_start, goal=run_goal, params=params,
                            gains=gains, limits=limits, period_s=period, stop_radius_m=eps,
                            t_max_s=run_t_max, heading_tolerance_rad=math.radians(tol),
                            scenario=name, controller=controller,
                            controller_gains=peer_gains, controller_fmu=controller_fmu,
                            sensors=sensors))
    return Scenario(name=name, description=description, runs=tuple(runs), path=path,
                    fmu=_file_field(data, "fmu", path), fmu_map=_file_field(data, "fmu_map", path))


def _file_field(data: Mapping[str, Any], key: str, path: Path | None) -> Path | None:
    """A file named by the scenario, relative to the scenario file's folder."""
    value = data.get(key)
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise ConfigError(key, f"must be a file path, got {value!r}",
                          f'write e.g. {key} = "robot.{"fmu" if key == "fmu" else "toml"}"')
    p = Path(value).expanduser()
    return p if p.is_absolute() or path is None else path.parent / p


def resolve_scenario_path(name_or_path: str | Path | None = None) -> Path:
    """A file path as is; a bare name (``"fig9"``) from the shipped scenarios folder."""
    if name_or_path is None:
        name_or_path = DEFAULT_SCENARIO
    p = Path(name_or_path)
    if p.exists() or len(p.parts) > 1:
        return p
    if p.suffix == ".toml":
        # ``fig11.toml`` with no such file here: the shipped one of that name, if any
        shipped = scenarios_dir() / p.name
        return shipped if shipped.is_file() else p
    return scenarios_dir() / f"{p.name}.toml"


def shipped_names(batch_specs: bool = True) -> list[str]:
    """The shipped scenarios' names (``scenarios/``), sorted; without the batch specs (files
    with a ``[grid]``, ``[[list]]``, ``[random]`` or ``[sweep]``) when ``batch_specs`` is
    false: what ``wmr run`` can run."""
    names = []
    for path in sorted(scenarios_dir().glob("*.toml")):
        if not batch_specs:
            try:
                data = tomllib.loads(path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
                continue
            if any(key in data for key in BATCH_TABLES):
                continue
        names.append(path.stem)
    return names


def read_toml(path: Path, field: str = "scenario", fix: str | None = None
              ) -> tuple[dict[str, Any], bytes]:
    """The parsed TOML of ``path`` and its bytes; every failure is one :class:`ConfigError`
    line naming ``field`` (missing, unreadable, not a regular file, larger than
    :data:`MAX_TOML_BYTES`, not UTF-8, not TOML, nested too deeply).

    ``fix`` says what to give instead of a missing or unusable file; by default a ``.toml``
    file or one of the shipped scenarios.  Scenarios, batch specs and variable maps (``--map``)
    are all read here, through :func:`wmr.infra.inputs.read_input`.
    """
    try:
        raw = read_input(path, field, max_bytes=MAX_TOML_BYTES, what="a TOML file",
                         fix=fix or "give a .toml file")
    except FileNotFoundError:
        if fix is None:
            # a scenario's suggestions leave out the batch specs, which wmr run refuses
            shipped = ", ".join(shipped_names(batch_specs=field != "scenario"))
            fix = f"give a path to a .toml file or one of: {shipped}"
        raise ConfigError(field, f"no such file: {path}", fix) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(field, f"{path} is not UTF-8 text (byte 0x{raw[exc.start]:02x} at "
                          f"offset {exc.start})", "save the file as UTF-8") from None
    try:
        return tomllib.loads(text), raw
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(field, f"{path} is not valid TOML: {exc}", "fix the syntax") from None
    except RecursionError:
        raise ConfigError(field, f"{path} nests arrays or tables too deeply",
                          "flatten the file") from None


def load_scenario(name_or_path: str | Path | None = None) -> Scenario:
    """Read, validate and expand a scenario file (default: ``fig11``)."""
    path = resolve_scenario_path(name_or_path)
    data, _ = read_toml(path)
    return parse_scenario(data, source=str(path), path=path)


def expand(scenario: Scenario) -> list[RunSpec]:
    """The runs of a scenario, one :class:`RunSpec` each."""
    return list(scenario.runs)


#: ``(x_m, y_m, heading_deg)``, as on the command line.
PoseDeg = tuple[float, float, float]


def _pose_input(value: Pose | Sequence[float] | None, name: str) -> Pose | PoseDeg | None:
    """A Pose as is (heading in rad); a sequence as ``(x_m, y_m, heading_deg)`` floats."""
    if value is None or isinstance(value, Pose):
        return value
    fix = "give three numbers: x and y in metres, the heading in degrees"
    if isinstance(value, str | bytes) or not hasattr(value, "__len__") or len(value) != 3:
        raise ConfigError(name, f"must be (x_m, y_m, heading_deg), got {value!r}", fix)
    try:
        return (float(value[0]), float(value[1]), float(value[2]))
    except (TypeError, ValueError):
        raise ConfigError(name, f"must be (x_m, y_m, heading_deg), got {value!r}",
                          fix) from None


def _by_name(value: Mapping[str, Any] | None, name: str) -> dict[str, Any] | None:
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise ConfigError(name, f"must map names to numbers, got {type(value).__name__}",
                          f"give e.g. {name}={{'NAME': VALUE}}")
    return dict(value)


@dataclass(frozen=True)
class Overrides:
    """What changes of a scenario's run (:func:`with_overrides`); ``None`` keeps the run's.
    Checked when made, each error naming its field; the values are checked against the run
    by :func:`with_overrides`.

    Attributes
    ----------
    start, goal
        A :class:`~wmr.core.plant.Pose` (heading in rad), or ``(x_m, y_m, heading_deg)`` as
        typed on the command line.
    name
        The run's new name.
    params, gains, limits
        Robot parameters, PI gains and limits by name: they replace the named fields only.
    period_s, stop_radius_m, max_time_s, heading_tolerance_deg
        The control period, the stop radius epsilon and the run's time limit, s and m; the
        heading tolerance, deg.
    controller, controller_gains
        The controller by its registered name (its gains then start from its defaults), and
        its own gains by name (replacing the named gains of the (new) controller).
    sensors
        A sensor preset (``gps``, ``raw``) or ``off`` (``docs/sensing.md``), a whole
        :class:`~wmr.core.sensing.config.SensorConfig`, or fields of the ``[sensors]`` table
        by name with their values (over the run's sensors, or the defaults').
    sensor
        Fields of the ``[sensors]`` table over those, as typed by a user (``wmr run --sensor
        NAME=VALUE``: a number may be text); errors name ``sensor NAME``.
    """

    start: Pose | Sequence[float] | None = None
    goal: Pose | Sequence[float] | None = None
    name: str | None = None
    params: Mapping[str, float] | None = None
    gains: Mapping[str, float] | None = None
    limits: Mapping[str, float] | None = None
    period_s: float | None = None
    stop_radius_m: float | None = None
    max_time_s: float | None = None
    heading_tolerance_deg: float | None = None
    controller: str | None = None
    controller_gains: Mapping[str, float] | None = None
    sensors: str | SensorConfig | Mapping[str, Any] | None = None
    sensor: Mapping[str, float | str] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", _pose_input(self.start, "start"))
        object.__setattr__(self, "goal", _pose_input(self.goal, "goal"))
        for name in ("params", "gains", "limits", "controller_gains"):
            object.__setattr__(self, name, _by_name(getattr(self, name), name))
        if self.sensors is not None and not isinstance(self.sensors,
                                                       str | SensorConfig | Mapping):
            raise ConfigError("sensors", "must be a preset's name, off, a SensorConfig or "
                              f"[sensors] fields by name, got {type(self.sensors).__name__}",
                              "give e.g. sensors='gps'")
        if self.sensor is not None and not isinstance(self.sensor, Mapping):
            raise ConfigError("sensor", f"must map [sensors] fields to values, got "
                              f"{type(self.sensor).__name__}",
                              "give e.g. sensor={'gps_sigma_m': 0.05}")
        for name in ("period_s", "stop_radius_m", "max_time_s", "heading_tolerance_deg"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool)
                                      or not isinstance(value, int | float)
                                      or not math.isfinite(value)):
                raise ConfigError(name, f"must be a finite number, got {value!r}",
                                  "give a number in the unit its name ends in")


def _sensors(current: SensorConfig | None, o: Overrides) -> SensorConfig | None:
    """The run's sensors ``current`` with the overrides' ``sensors``, then ``sensor``, over
    them."""
    cfg = current
    if isinstance(o.sensors, SensorConfig):
        cfg = o.sensors
    elif isinstance(o.sensors, str):
        cfg = override_sensors(cfg, o.sensors, None)
    elif o.sensors:
        cfg = sensor_config(o.sensors, cfg)
    if o.sensor:
        cfg = override_sensors(cfg, None, [f"{k}={v}" for k, v in o.sensor.items()])
    return cfg


def with_overrides(spec: RunSpec, overrides: Overrides | None = None) -> RunSpec:
    """The run ``spec`` with ``overrides`` (:class:`Overrides`) merged in, checked.

    Raises
    ------
    ConfigError
        A value the run cannot take, naming its field (``start.x_m``, ``gains.K_x``,
        ``control_period_s``, ``sensors.gps_rate_hz``).
    """
    o = Overrides() if overrides is None else overrides
    changes: dict[str, Any] = {}
    for field in ("start", "goal"):
        pose = getattr(o, field)
        if pose is not None:
            changes[field] = pose if isinstance(pose, Pose) else _pose(list(pose), field)
    if o.name is not None:
        changes["name"] = o.name
    if o.gains:
        changes["gains"] = _build(Gains, o.gains, "gains", spec.gains)
    if o.limits:
        changes["limits"] = _build(Limits, o.limits, "limits", spec.limits)
    if o.params:
        changes["params"] = _build(RobotParams, o.params, "params", spec.params)
    if o.period_s is not None:
        changes["period_s"] = check_positive("control_period_s", o.period_s)
    if o.stop_radius_m is not None:
        changes["stop_radius_m"] = check_positive("stop_radius_m", o.stop_radius_m)
    if o.max_time_s is not None:
        changes["t_max_s"] = check_positive("max_time_s", o.max_time_s)
    if o.heading_tolerance_deg is not None:
        changes["heading_tolerance_rad"] = math.radians(
            check_positive("heading_tolerance_deg", o.heading_tolerance_deg))
    if o.controller is not None and o.controller != spec.controller:
        changes["controller"] = o.controller
        changes["controller_gains"] = ()
    if o.controller_gains:
        base = dict(() if "controller_gains" in changes else spec.controller_gains)
        base.update(o.controller_gains)
        changes["controller_gains"] = _peer_gains(changes.get("controller", spec.controller),
                                                  base)
    if o.sensors is not None or o.sensor:
        changes["sensors"] = _sensors(spec.sensors, o)
    return replace(spec, **changes)


__all__ = [
    "DEFAULT_SCENARIO",
    "Overrides",
    "PoseDeg",
    "Scenario",
    "expand",
    "heading_looks_like_radians",
    "load_scenario",
    "parse_scenario",
    "resolve_scenario_path",
    "shipped_names",
    "unknown_field",
    "with_overrides",
]

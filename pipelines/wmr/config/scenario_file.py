"""A run written back as a scenario file: the effective scenario a log attaches.

:func:`run_spec_toml` gives a one-run scenario (TOML) that :func:`wmr.config.scenario.load_scenario`
and ``wmr run`` read back into the very same :class:`~wmr.core.runspec.RunSpec`, field for field
and bit for bit: every parameter, gain, limit and setting is written out (not only those that differ
from the defaults, so that a later change of a default cannot change the replayed run), floats
in their shortest round-trip form, and angles in degrees chosen so that ``math.radians`` gives
the run's radians back exactly.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import fields

from wmr.config.scenario import parse_scenario
from wmr.core.plant import Pose
from wmr.core.runspec import RunSpec
from wmr.infra.version import __version__


def _float(value: float) -> str:
    """A TOML float that parses back to exactly ``value`` (``repr`` round-trips)."""
    text = repr(float(value))
    return text if ("." in text or "e" in text or "n" in text) else f"{text}.0"


def exact_degrees(rad: float) -> float:
    """Degrees ``d`` with ``math.radians(d) == rad`` exactly, when such a float exists.

    The shortest decimal that maps back is preferred (``30.0``, not ``29.999999999999996``);
    ``math.degrees`` alone can miss by one unit in the last place, so its neighbours are tried
    next.  Every angle that came from degrees (a scenario file, the command line) has one.
    """
    # remembered: a batch's runs share most of their angles (the heading tolerance, the
    # goal's), and a search costs up to 17 formattings.  Keyed by the sign too: -0.0 equals
    # 0.0 but has degrees of its own
    return _exact_degrees(rad, math.copysign(1.0, rad))


@functools.lru_cache(maxsize=1024)
def _exact_degrees(rad: float, sign: float) -> float:
    d = math.degrees(rad)
    for digits in range(1, 18):
        short = float(f"{d:.{digits}g}")
        if math.radians(short) == rad:
            return short
    lo = hi = d
    for _ in range(64):
        lo, hi = math.nextafter(lo, -math.inf), math.nextafter(hi, math.inf)
        for cand in (lo, hi):
            if math.radians(cand) == rad:
                return cand
    return d


def _pose(pose: Pose) -> str:
    return (f"[{_float(pose.x_m)}, {_float(pose.y_m)}, "
            f"{_float(exact_degrees(pose.heading_rad))}]")


def _basic_string(text: str) -> str:
    escaped = text.replace("\\", "\\\\").replace('"', '\\"')
    return '"' + "".join(c if c.isprintable() else f"\\u{ord(c):04x}" for c in escaped) + '"'


def _table(name: str, values: Mapping[str, float]) -> list[str]:
    return ["", f"[{name}]", *(f"{k} = {_float(v)}" for k, v in values.items())]


def _value(value: object) -> str:
    """A TOML value of a sensors field: string, integer, float, or array of them."""
    if isinstance(value, str):
        return _basic_string(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return _float(float(value))  # type: ignore[arg-type]


def run_spec_toml(spec: RunSpec) -> str:
    """The one-run scenario file (TOML text) of ``spec``.

    Its top-level ``name`` is the run's scenario (``spec.scenario``, else the run's name); its
    single ``[[runs]]`` entry carries the run's name, start and goal.
    """
    lines = [
        f"# The effective scenario of the run {spec.name!r}, written by wmr-cosim {__version__}.",
        "# 'wmr run THIS_FILE' repeats the run exactly.",
        f"name = {_basic_string(spec.scenario or spec.name)}",
        f"controller = {_basic_string(spec.controller)}",
        f"control_period_s = {_float(spec.period_s)}",
        f"stop_radius_m = {_float(spec.stop_radius_m)}",
        f"heading_tolerance_deg = {_float(exact_degrees(spec.heading_tolerance_rad))}",
        f"max_time_s = {_float(spec.t_max_s)}",
    ]
    if spec.controller_fmu is not None:  # "": the built controller FMU
        lines.append("controller_fmu = " + ("true" if spec.controller_fmu == ""
                                            else _basic_string(spec.controller_fmu)))
    lines += _table("params", spec.params.as_dict())
    lines += _table("gains", spec.gains.as_dict())
    lines += _table("limits", spec.limits.as_dict())
    if spec.controller_gains:
        lines += _table("controller_gains", dict(spec.controller_gains))
    if spec.sensors is not None:
        lines += ["", "[sensors]", *(f"{f.name} = {_value(getattr(spec.sensors, f.name))}"
                                     for f in fields(spec.sensors))]
    lines += ["", "[[runs]]", f"name = {_basic_string(spec.name)}",
              f"start = {_pose(spec.start)}", f"goal = {_pose(spec.goal)}", ""]
    return "\n".join(lines)


def check_round_trip(spec: RunSpec, text: str) -> bool:
    """Whether ``text`` reads back into ``spec`` exactly (what a log promises)."""
    import tomllib

    runs = parse_scenario(tomllib.loads(text)).runs
    return len(runs) == 1 and runs[0] == spec


__all__ = ["check_round_trip", "exact_degrees", "run_spec_toml"]

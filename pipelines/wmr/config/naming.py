"""The one place that names a run and its default log from what makes it differ.

A run started from a scenario with overrides (``--start``, ``--goal``, ``--param``, ``--gain``,
``--limit``, ``--period``, ``--stop-radius``, ``--max-time``, another controller, another FMU
or FMI version) is named after its differences from the scenario's own run, so that its log
never overwrites the scenario's (``runs/fig11.mcap``) nor passes for it in its ``run`` record:
``fig11-m=40-K_ps=0.3-to_5_5_30deg``.  A run that does not differ keeps the scenario's name.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Final

from wmr.core.plant import Pose
from wmr.core.runspec import RunSpec
from wmr.core.sensing.config import PRESETS, SensorConfig, preset
from wmr.infra.paths import MAX_STEM_BYTES, safe_filename

#: Longest name kept whole; a longer one is cut and ends in a hash of the whole.
MAX_NAME_CHARS = 120


def pose_token(label: str, pose: Pose) -> str:
    """``to_20_10_0deg``: a pose as typed on the command line (heading in degrees)."""
    return (f"{label}_{pose.x_m:.10g}_{pose.y_m:.10g}_"
            f"{math.degrees(pose.heading_rad):.10g}deg")


def _value_tokens(base: Mapping[str, float], new: Mapping[str, float]) -> list[str]:
    return [f"{k}={v:.10g}" for k, v in new.items() if base.get(k) != v]


def spec_tokens(base: RunSpec, spec: RunSpec) -> list[str]:
    """One token per field in which ``spec`` differs from ``base``, in a fixed order."""
    tokens: list[str] = []
    if spec.controller != base.controller:
        tokens.append(spec.controller)
    tokens += _value_tokens(base.params.as_dict(), spec.params.as_dict())
    tokens += _value_tokens(base.gains.as_dict(), spec.gains.as_dict())
    tokens += _value_tokens(base.limits.as_dict(), spec.limits.as_dict())
    base_peer = dict(base.controller_gains) if spec.controller == base.controller else {}
    tokens += _value_tokens(base_peer, dict(spec.controller_gains))
    for label, old, new in (("period", base.period_s, spec.period_s),
                            ("stop", base.stop_radius_m, spec.stop_radius_m),
                            ("tmax", base.t_max_s, spec.t_max_s)):
        if old != new:
            tokens.append(f"{label}={new:.10g}")
    if spec.heading_tolerance_rad != base.heading_tolerance_rad:
        tokens.append(f"htol={math.degrees(spec.heading_tolerance_rad):.10g}deg")
    if spec.controller_fmu != base.controller_fmu:
        tokens.append("controller_fmu" if spec.controller_fmu is not None
                      else "controller_python")
    if spec.sensors != base.sensors:
        tokens += (["sensors_off"] if spec.sensors is None
                   else sensor_tokens(base.sensors, spec.sensors))
    if spec.start != base.start:
        tokens.append(pose_token("from", spec.start))
    if spec.goal != base.goal:
        tokens.append(pose_token("to", spec.goal))
    return tokens


#: Short names of the ``[sensors]`` fields in run names (``gps_sigma_m=0.05`` is ``gps_sd=0.05``).
SENSOR_ALIASES: Final[dict[str, str]] = {
    "estimator": "est", "seed": "seed", "gps_rate_hz": "gps_hz", "gps_latency_s": "gps_lag",
    "gps_sigma_m": "gps_sd", "gps_bias_walk_m_per_sqrt_s": "gps_walk",
    "gps_dropout_probability": "gps_drop", "gps_dropout_windows": "gps_gaps", "heading": "hdg",
    "compass_sigma_deg": "cmp_sd", "compass_rate_hz": "cmp_hz", "compass_latency_s": "cmp_lag",
    "encoder_counts_per_rev": "enc_cpr", "encoder_rate_hz": "enc_hz",
    "odometry_noise_m2_per_m": "odo_var", "wheel_radius_error_frac": "r_err",
    "initial_heading_sigma_deg": "hdg0_sd",
}
#: Longest sensors part of a run name (``sensors_gps-gps_sd=0.1-...``) kept whole; a longer
#: one keeps the tokens that fit and ends in ``Nmore_HASH``, HASH of the whole sensors table.
MAX_SENSOR_CHARS = 48


def _sensor_value(value: object) -> str:
    if isinstance(value, tuple):  # gps_dropout_windows: 20_25+30_35
        return "+".join("_".join(f"{t:.10g}" for t in w) for w in value)
    return f"{value:.10g}" if isinstance(value, float) else str(value)


def _sensor_diffs(before: SensorConfig, after: SensorConfig) -> list[str]:
    return [f"{SENSOR_ALIASES.get(f.name, f.name)}={_sensor_value(getattr(after, f.name))}"
            for f in fields(SensorConfig) if getattr(before, f.name) != getattr(after, f.name)]


def sensor_tokens(base: SensorConfig | None, sensors: SensorConfig) -> list[str]:
    """Short tokens for a run's ``sensors`` (``base``: the scenario run's, or None).

    ``sensors_gps`` for the ``gps`` preset as it is; else the table nearest to ``sensors`` of
    the scenario run's (or the defaults), ``sensors``, and the presets, ``sensors_gps``,
    followed by the fields that differ from it under their short names
    (:data:`SENSOR_ALIASES`): ``sensors_gps-gps_sd=0.1``.  A sensors part longer than
    :data:`MAX_SENSOR_CHARS` keeps the tokens that fit and ends with how many more differ and
    a hash of the whole table (``4more_bcafb73d``), so that two runs with other sensors never
    share a name; the log's ``run`` record holds the whole table.  (Names were once
    every differing field in full, ``sensors-estimator=ekf-gps_latency_s=0.05-...``: about
    110 characters, escaped in Rerun's entity paths.)
    """
    references = [("sensors", base if base is not None else SensorConfig()),
                  *((f"sensors_{name}", preset(name)) for name in PRESETS)]
    # fewest differences; the first on a tie: the scenario's own table before a preset
    label, diffs = min(((lab, _sensor_diffs(ref, sensors)) for lab, ref in references),
                       key=lambda item: len(item[1]))
    tokens = [label, *diffs]
    if len("-".join(tokens)) <= MAX_SENSOR_CHARS:
        return tokens
    digest = hashlib.sha256(repr(sensors.as_dict()).encode()).hexdigest()[:8]
    kept, budget = [label], MAX_SENSOR_CHARS - len(label) - len(f"-99more_{digest}")
    for token in diffs:
        if len(token) + 1 > budget:
            break
        kept.append(token)
        budget -= len(token) + 1
    return [*kept, f"{len(diffs) - len(kept) + 1}more_{digest}"]


def fmu_tokens(fmi_version: int, fmu: str | Path | None, default_fmi: int = 3) -> list[str]:
    """Tokens for a plant other than the project's own FMI ``default_fmi`` build."""
    tokens = []
    if fmu is not None:
        tokens.append(f"fmu_{Path(fmu).stem}")
    elif fmi_version != default_fmi:
        tokens.append(f"fmi{fmi_version}")
    return tokens


def variant_name(base_name: str, tokens: Iterable[str]) -> str:
    """``base_name`` followed by ``tokens``, joined by ``-``; cut to :data:`MAX_NAME_CHARS`
    with a hash of the whole so that two long names stay apart."""
    name = "-".join([base_name, *tokens])
    if len(name) <= MAX_NAME_CHARS:
        return name
    digest = hashlib.sha256(name.encode()).hexdigest()[:10]
    return f"{name[:MAX_NAME_CHARS - 11]}~{digest}"


def run_name(base: RunSpec, spec: RunSpec, extra: Sequence[str] = ()) -> str:
    """Name of ``spec``, a variant of the scenario's run ``base`` (itself if no change)."""
    return variant_name(base.name, [*spec_tokens(base, spec), *extra])


#: A file name stem for a run name: :func:`wmr.infra.paths.safe_filename` itself (kept under this
#: name for its callers), which cuts by bytes after encoding for every file the project names.
file_stem = safe_filename


def default_log_path(name: str, folder: str | Path = "runs", suffix: str = ".mcap") -> Path:
    """``runs/NAME.mcap``: where a run's log goes when no ``--out`` is given (its name
    :func:`file_stem`, short enough for any file system however the name is written); with
    another ``folder`` and ``suffix``, where a command writes another file of a run
    (``ssp/NAME.ssp`` of ``wmr ssp export``)."""
    return Path(folder) / f"{file_stem(name)}{suffix}"


def plural(n: int, noun: str) -> str:
    """``1 run``, ``2 runs``, ``0 runs``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


#: Names shown by :func:`name_list` before it ends the list with ``...``.
LISTED_NAMES = 6


def name_list(names: Sequence[str], noun: str = "run", shown: int = LISTED_NAMES) -> str:
    """``its 12 runs: a, b, c, d, e, f, ...``: how many there are, and the first ``shown``,
    the list ended with ``...`` when cut so that it never passes for the whole of them."""
    head = ", ".join(names[:shown]) + (", ..." if len(names) > shown else "")
    return f"its {plural(len(names), noun)}: {head}" if names else f"no {noun}s"


__all__ = ["MAX_STEM_BYTES", "SENSOR_ALIASES", "default_log_path", "file_stem", "fmu_tokens",
           "name_list", "plural", "pose_token", "run_name", "sensor_tokens", "spec_tokens",
           "variant_name"]

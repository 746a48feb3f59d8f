r"""The paper's PI stabiliser against the peers and the time-optimal manoeuvre (``wmr benchmark``).

Every case of a scenario set is run by each controller on **one** FMU plant, with the same
wheel servos, command limits and torque limit (:mod:`wmr.core.control.peers`), and solved as a
minimum-time optimal control problem under the same limits
(:func:`wmr.adapters.ocp.solve_optimal` with ``OptimalLimits.like(spec.limits)``: torque, wheel
speed, :math:`v` and :math:`\omega`, forward only), whose torques are replayed open-loop on the same
FMU.

Figures per run (SI units):

* ``time_to_goal_s``: closed loop, the first step at which the run has converged (inside the
  stop radius :math:`\varepsilon`, heading within the tolerance, at rest); optimal, the final
  time :math:`T^*` (it ends at rest, on the goal pose);
* ``time_to_radius_s``: the first time B is within :math:`\varepsilon` of the goal;
* ``path_length_m``: :math:`\sum |B_{k+1} - B_k|` along the FMU's path;
* ``energy_net_j``, ``energy_positive_j``, ``energy_abs_j``: the motors' work as
  :mod:`wmr.core.energy` defines it for every command (net; delivered, none recovered; driving and
  braking both counted); the net work is about 0 for a rest-to-rest manoeuvre without
  friction;
* ``torque_sq_integral_n2m2s``: :math:`\int (\tau_r^2 + \tau_l^2)\,dt`;
* ``peak_torque_nm``: :math:`\max |\tau|`;
* ``final_position_error_m``, ``final_heading_error_rad``: at the end of the run (optimal:
  of the open-loop replay);
* ``time_ratio``, ``path_ratio``, ``energy_ratio`` (of ``energy_positive_j``), ``effort_ratio``:
  the run's figure over the optimal's for the same case (``None`` when either is missing).

Each run is logged to ``OUT/logs/<controller>/<case>.mcap``: closed-loop runs as ``wmr run``
logs them; the optimal as :func:`write_optimal_log` does (FMU driven open-loop).
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import OPEN_LOOP_TOPICS, McapOpener
from wmr.apps.run import (
    FULL_LOGS,
    LogPolicy,
    run_to_log,
    scenario_attachment_name,
)
from wmr.apps.tune import with_gains
from wmr.config.scenario import load_scenario
from wmr.config.scenario_file import run_spec_toml
from wmr.core.control import Limits, registry
from wmr.core.energy import ENERGY_KEYS, wheel_work
from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams
from wmr.core.runlog import LogHeader
from wmr.core.runspec import RunSpec
from wmr.core.signals import COLUMN, PLANT_SIGNALS, SIGNALS
from wmr.infra.version import __version__

#: The suffix of a row with the controller's tuned gains (``pi-tuned``).
TUNED_SUFFIX: Final = "-tuned"


def controller_rows(names: Sequence[str]) -> dict[str, tuple[str, bool]]:
    """Benchmark rows of the controllers ``names``: label -> (controller, use the tuned gains);
    each controller, then ``NAME-tuned`` when it declares tuned gains
    (:mod:`wmr.core.control.registry`)."""
    rows: dict[str, tuple[str, bool]] = {}
    for name in names:
        rows[name] = (name, False)
        if registry.get(name, "controllers").tuned:
            rows[f"{name}{TUNED_SUFFIX}"] = (name, True)
    return rows


#: The default rows: the built-in controllers, default and tuned gains (a plug-in's rows are
#: asked for by name: ``--controllers pi,NAME``).
CONTROLLERS: Final[dict[str, tuple[str, bool]]] = controller_rows(registry.BUILTIN_NAMES)


def controller_row(label: str, tuned: Mapping[str, Mapping[str, float]]) -> tuple[str, bool]:
    """``(controller, use the tuned gains)`` of the row ``label``: a controller's name, or
    ``NAME-tuned`` for one with tuned gains (declared, or in ``tuned``).

    Raises
    ------
    ConfigError
        ``controllers``: an unknown label (listing the known ones), or ``NAME-tuned`` of a
        controller without tuned gains.
    """
    from wmr.infra.errors import ConfigError

    name, use_tuned = label, False
    if label.endswith(TUNED_SUFFIX) and label not in registry.names():
        name, use_tuned = label[:-len(TUNED_SUFFIX)], True
    if name not in registry.names():
        known = [*CONTROLLERS, *(n for n in registry.names() if n not in CONTROLLERS)]
        raise ConfigError("controllers", f"unknown controller {label!r}",
                          f"one of: {', '.join(known)}")
    registry.get(name, "controllers")  # a plug-in that does not load: its one line
    if use_tuned and not tuned.get(name):
        raise ConfigError("controllers", f"{name} has no tuned gains",
                          f"run 'wmr tune --controller {name} --save FILE.json' and give "
                          "tuned=FILE.json, or ask for the row " + repr(name))
    return name, use_tuned


OPTIMAL: Final = "optimal"
DEFAULT_SCENARIOS: Final = ("fig9", "fig10")
#: Columns of the CSV/Parquet table and of the ``--json`` objects, in order.
FIELDS: Final = (
    "case", "scenario", "controller", "status", "time_to_goal_s", "time_to_radius_s",
    "path_length_m", *ENERGY_KEYS, "torque_sq_integral_n2m2s", "peak_torque_nm",
    "final_position_error_m", "final_heading_error_rad", "time_ratio", "path_ratio",
    "energy_ratio", "effort_ratio", "message", "mcap",
)
_X, _Y = COLUMN["x_m"], COLUMN["y_m"]
_N_PLANT = len(PLANT_SIGNALS)
_C_TAU_R, _C_TAU_L = COLUMN["tau_r_nm"], COLUMN["tau_l_nm"]


def _num(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def safe_name(name: str) -> str:
    """A case name as a file name."""
    from wmr.infra.paths import safe_filename

    return safe_filename(name)


def fmu_attachments(plant: FmuPlant) -> dict[str, tuple[str, bytes]]:
    """The FMU's ``modelDescription.xml`` as a log attachment (read as ``wmr run`` reads it)."""
    return {"modelDescription.xml": ("application/xml", plant.model_description_xml)}


class _RadiusTracker:
    """A block sink that passes blocks on and notes when B first enters the stop radius."""

    def __init__(self, sink: Any, goal: Pose, radius_m: float) -> None:
        self.sink = sink
        self.xd, self.yd = goal.x_m, goal.y_m
        self.radius = radius_m
        self.t_s: float | None = None

    def write_block(self, t_ns: npt.NDArray[np.int64], block: npt.NDArray[np.float64]) -> None:
        if self.t_s is None:
            d = np.hypot(block[:, _X] - self.xd, block[:, _Y] - self.yd)
            inside = np.flatnonzero(d <= self.radius)
            if inside.size:
                self.t_s = float(t_ns[inside[0]]) * 1e-9
        if self.sink is not None:
            self.sink.write_block(t_ns, block)


#: A run's record without its log.
_NO_LOG: Final = LogPolicy("none")


def run_logged(spec: RunSpec, plant: FmuPlant,
               mcap: Path | None) -> tuple[dict[str, Any], float | None]:
    """One closed-loop run of ``spec`` on ``plant`` as ``wmr run`` makes it
    (:func:`~wmr.apps.run.run_to_log`: the same law, the same log, byte for byte), logged to
    ``mcap`` if given.

    Returns
    -------
    (dict, float or None)
        The run's record (``docs/results.md``) and the time B first entered the stop
        radius, s.
    """
    tracker = _RadiusTracker(None, spec.goal, spec.stop_radius_m)
    # no log: the record alone (nothing is written at the path given for none)
    record = run_to_log(spec, mcap if mcap is not None else Path(os.devnull), plant,
                        also=tracker, log=FULL_LOGS if mcap is not None else _NO_LOG)
    return record, tracker.t_s


@dataclass
class OptimalRun:
    """An optimal manoeuvre and its open-loop replay on the FMU, with the benchmark figures.

    Attributes
    ----------
    status
        The solver's ``solved``, ``infeasible`` or ``failed``.
    message
        The solver's message.
    final_time_s
        :math:`T^*`, s (None unless solved).
    figures
        The benchmark figures of the replay (:data:`FIELDS` names).
    """

    status: str
    message: str
    final_time_s: float | None
    figures: dict[str, Any] = field(default_factory=dict)


def replay_figures(replay: Any, goal: Pose, stop_radius_m: float) -> dict[str, Any]:
    r"""Figures of an open-loop replay (:class:`wmr.adapters.ocp.OpenLoopReplay`).

    Energy (:func:`wmr.core.energy.wheel_work`) and effort
    :math:`\sum_k h_k (\tau_{r,k}^2 + \tau_{l,k}^2)` are integrated per FMU step with the
    step's held torque.
    """
    t = np.asarray(replay.t_s, dtype=float)
    x, y = replay.outputs["x"], replay.outputs["y"]
    wr, wl = replay.outputs["omega_r"], replay.outputs["omega_l"]
    tau = np.asarray(replay.torques, dtype=float).reshape(-1, 2)
    h = np.diff(t)
    path = float(np.sum(np.hypot(np.diff(x), np.diff(y))))
    d = np.hypot(x - goal.x_m, y - goal.y_m)
    inside = np.flatnonzero(d <= stop_radius_m)
    return {
        "time_to_radius_s": float(t[inside[0]]) if inside.size else None,
        "path_length_m": path,
        **wheel_work(tau, np.column_stack([wr, wl]), h),
        "torque_sq_integral_n2m2s": float(np.sum(h * np.sum(tau**2, axis=1))),
        "peak_torque_nm": float(np.max(np.abs(tau))) if tau.size else 0.0,
        "final_position_error_m": float(replay.final_position_error_m),
        "final_heading_error_rad": abs(float(replay.final_heading_error_rad)),
    }


def replay_step_s(replay: Any) -> float:
    """The (equal) FMU step of an open-loop replay, s: each torque interval T / N is split in
    the same number of steps (:func:`wmr.adapters.ocp.replay_open_loop`)."""
    t = np.asarray(replay.t_s, dtype=float)
    return float((t[-1] - t[0]) / (len(t) - 1)) if len(t) > 1 else 0.0


def optimal_scenario(name: str, scenario: str, start: Pose, goal: Pose, params: RobotParams,
                     limits: Any, period_s: float) -> RunSpec:
    """The case of an optimal manoeuvre as a run of the PI (attached to the optimal's log).

    Limits the optimum did not have (``wmr optimal --torque-only``) are the PI's defaults.
    """
    pi = Limits()
    return RunSpec(name=name, start=start, goal=goal, params=params, period_s=period_s,
                   scenario=scenario or name, limits=Limits(**{
                       k: getattr(pi, k) if getattr(limits, k) is None else getattr(limits, k)
                       for k in ("torque_max_nm", "wheel_speed_max_radps", "v_max_mps",
                                 "omega_max_radps")}))


def write_optimal_log(path: Path, result: Any, replay: Any, plant: FmuPlant,
                      run: Mapping[str, object], record: Mapping[str, object],
                      scenario: RunSpec | None = None, scene: bool = False) -> None:
    """Log an optimal manoeuvre's open-loop FMU replay as a run log.

    ``/robot/pose`` and every plant column are the FMU's outputs (driven open-loop by the
    optimal torques, not the optimiser's states); ``/robot/torques`` holds the torques applied
    over the step that starts at the row (0 on the last row).  The controller topics are not
    written (:data:`wmr.adapters.mcap.OPEN_LOOP_TOPICS`): there is no controller.  Row ``n`` is at
    ``round(n h 1e9)`` ns, ``h`` the replay's (equal) FMU step, the ``control_period_s`` of
    the ``run`` record.  Attached: ``modelDescription.xml`` and the case as a scenario
    (:func:`optimal_scenario`), which ``wmr run`` runs with the PI.

    Parameters
    ----------
    path
        The ``.mcap`` file.
    result, replay
        :class:`wmr.adapters.ocp.OptimalResult` and its :class:`wmr.adapters.ocp.OpenLoopReplay`.
    plant
        The FMU replayed (for the attachment).
    run, record
        The ``run`` and ``result`` metadata records.
    scenario
        The case as a run (:func:`optimal_scenario`), attached as a scenario file; its
        robot is the one the scene draws.
    scene
        Also write the drawable topics (:mod:`wmr.adapters.mcap.scene`; ``wmr optimal``
        does).
    """
    n = len(replay.t_s)
    h_s = replay_step_s(replay)
    block = np.full((n, len(SIGNALS)), np.nan)
    for i, name in enumerate(OUTPUT_NAMES):
        block[:, i] = replay.outputs[name]
    tau = np.asarray(replay.torques, dtype=float).reshape(-1, 2)
    block[:, _C_TAU_R] = 0.0
    block[:, _C_TAU_L] = 0.0
    block[: tau.shape[0], _C_TAU_R] = tau[:, 0]
    block[: tau.shape[0], _C_TAU_L] = tau[:, 1]
    goal = result.goal
    # exact multiples of the step, never accumulated
    t_ns = np.round(np.arange(n) * (h_s * 1e9)).astype(np.int64)
    attachments = fmu_attachments(plant)
    if scenario is not None:
        attachments[scenario_attachment_name(scenario)] = (
            "application/toml", run_spec_toml(scenario).encode("utf-8"))
    # the robot drawn is the scenario's (the paper's without one); no stop radius: the
    # optimum has no controller whose phases or ring to draw
    robot = scenario.params if scenario is not None else RobotParams()
    header = LogHeader(run={**run, "control_period_s": h_s},
                       goal=(goal.x_m, goal.y_m, goal.heading_rad),
                       attachments=tuple((name, media_type, data)
                                         for name, (media_type, data) in attachments.items()),
                       half_track_m=robot.L, wheel_radius_m=robot.r, stop_radius_m=None)
    with McapOpener(path, scene=scene, topics=OPEN_LOOP_TOPICS)(header) as log:
        log.write_block(t_ns, block)
        log.close(record)


def optimal_metadata(name: str, scenario: str, start: Pose, goal: Pose, params: RobotParams,
                     limits: Any, objective: str, plant: FmuPlant,
                     period_s: float) -> dict[str, object]:
    """The ``run`` metadata record of an optimal log (same keys as a closed-loop run's)."""
    return {
        "name": name,
        "scenario": scenario,
        "controller": "optimal",
        "benchmark_label": OPTIMAL,
        "objective": objective,
        "start": {"x_m": start.x_m, "y_m": start.y_m, "heading_rad": start.heading_rad},
        "goal": {"x_m": goal.x_m, "y_m": goal.y_m, "heading_rad": goal.heading_rad},
        "params": params.as_dict(),
        "limits": {k: getattr(limits, k) for k in ("torque_max_nm", "wheel_speed_max_radps",
                                                   "v_max_mps", "omega_max_radps")},
        "control_period_s": period_s,
        "fmu_sha256": plant.sha256,
        "fmu_file": plant.fmu_path.name,
        "fmi_version": plant.fmi_version,
        "software_version": f"wmr-cosim {__version__}",
    }


def run_optimal(spec: RunSpec, plant: FmuPlant, mcap: Path | None) -> OptimalRun:
    """Solve the minimum-time manoeuvre of ``spec`` under its limits, replay it on ``plant``.

    A failed or infeasible solve is recorded, never raised.
    """
    from wmr.adapters.ocp import OptimalLimits, OptimalProblem, replay_open_loop, solve_optimal

    limits = OptimalLimits.like(spec.limits)
    try:
        res = solve_optimal(OptimalProblem(spec.start, spec.goal, spec.params, limits=limits))
    except Exception as exc:  # a solver failure is one row, not the end of the benchmark
        return OptimalRun("failed", f"{type(exc).__name__}: {exc}", None)
    if res.status != "solved":
        return OptimalRun(res.status, res.message, None)
    replay = replay_open_loop(res, plant, params=spec.params, start=spec.start,
                              control_period_s=spec.period_s)
    figs = replay_figures(replay, spec.goal, spec.stop_radius_m)
    figs["time_to_goal_s"] = res.final_time_s
    if mcap is not None:
        record = {"name": spec.name, "status": res.status, "message": res.message,
                  "final_time_s": res.final_time_s, **figs, "mcap": str(mcap)}
        write_optimal_log(mcap, res, replay, plant,
                          optimal_metadata(spec.name, spec.scenario, spec.start, spec.goal,
                                           spec.params, limits, "time", plant, spec.period_s),
                          {k: v for k, v in record.items() if v is not None}, scenario=spec)
        figs["mcap"] = str(mcap)
    return OptimalRun(res.status, res.message, res.final_time_s, figs)


def _ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or not math.isfinite(a) or not math.isfinite(b) or b <= 0.0:
        return None
    return a / b


def load_tuned(path: str | os.PathLike[str] | None) -> dict[str, dict[str, float]]:
    """Tuned gains by controller: those the built-in controllers declare
    (:mod:`wmr.core.control.registry`), with those of a ``wmr tune --save`` JSON file over
    them (which may name any registered controller)."""
    from wmr.infra.errors import ConfigError
    from wmr.infra.inputs import MAX_JSON_BYTES, read_input

    gains = {n: dict(registry.get(n).tuned) for n in registry.BUILTIN_NAMES
             if registry.get(n).tuned}
    if path is None:
        return gains
    fix = "give a file written by 'wmr tune --save'"
    try:
        data = json.loads(read_input(path, "tuned", max_bytes=MAX_JSON_BYTES,
                                     what="a tuned-gains file", fix=fix).decode("utf-8"))
    except ConfigError:  # a ValueError too: already the one line
        raise
    except (OSError, ValueError, RecursionError) as exc:
        raise ConfigError("tuned", f"cannot read {path}: {exc}", fix) from None
    if not isinstance(data, dict):
        raise ConfigError("tuned", f"{path} is not a JSON object of controller -> gains")
    for name, g in data.items():
        if name not in registry.names() or not isinstance(g, dict):
            raise ConfigError("tuned", f"{path}: unexpected entry {name!r}",
                              f"controllers: {', '.join(registry.names())}")
        gains[name] = {k: float(v) for k, v in g.items()}
    return gains


def benchmark_specs(scenarios: Sequence[str]) -> list[RunSpec]:
    """The runs of the named scenarios (names or TOML paths), in order."""
    specs: list[RunSpec] = []
    for s in scenarios:
        specs.extend(load_scenario(s).runs)
    return specs


def run_benchmark(specs: Sequence[RunSpec], plant: FmuPlant, out_dir: Path | None = None,
                  controllers: Sequence[str] = tuple(CONTROLLERS),
                  tuned: Mapping[str, Mapping[str, float]] | None = None,
                  optimal: bool = True,
                  progress: Callable[[str, str], None] | None = None) -> list[dict[str, Any]]:
    """Every case by every controller, and the optimum; one row per (case, controller).

    Parameters
    ----------
    specs
        The cases.
    plant
        The FMU, shared by every run and by the optimal replays.
    out_dir
        Logs go to ``out_dir/logs/<controller>/<case>.mcap``; None: no logs.
    controllers
        Row labels (:func:`controller_row`: a registered controller's name, or
        ``NAME-tuned``); default :data:`CONTROLLERS`.
    tuned
        Tuned gains per controller (default :func:`load_tuned`).
    optimal
        Also solve and replay the optimum (and fill the ratios).
    progress
        ``progress(case, controller)`` before each run.

    Returns
    -------
    list of dict
        Rows with the :data:`FIELDS` keys (``None`` for a missing figure).
    """
    tuned_gains = load_tuned(None) if tuned is None else tuned
    rows_of = {label: controller_row(label, tuned_gains) for label in controllers}
    logs = None if out_dir is None else out_dir / "logs"
    rows: list[dict[str, Any]] = []
    for spec in specs:
        case = spec.name
        fname = f"{safe_name(case)}.mcap"
        opt: OptimalRun | None = None
        if optimal:
            if progress is not None:
                progress(case, OPTIMAL)
            opt = run_optimal(spec, plant, None if logs is None else logs / OPTIMAL / fname)
        case_rows: list[dict[str, Any]] = []
        for label in controllers:
            if progress is not None:
                progress(case, label)
            name, use_tuned = rows_of[label]
            gains = tuned_gains.get(name, {}) if use_tuned else {}
            run_spec = with_gains(spec, name, gains)
            mcap = None if logs is None else logs / label / fname
            res, t_radius = run_logged(run_spec, plant, mcap)
            case_rows.append({
                "case": case, "scenario": spec.scenario, "controller": label,
                "status": res["status"], "time_to_radius_s": _num(t_radius),
                **{k: _num(res[k]) for k in ("time_to_goal_s", "path_length_m", *ENERGY_KEYS,
                                             "torque_sq_integral_n2m2s", "peak_torque_nm",
                                             "final_position_error_m",
                                             "final_heading_error_rad")},
                "message": res["message"], "mcap": res["mcap"],
            })
        if opt is not None:
            f = opt.figures
            case_rows.append({
                "case": case, "scenario": spec.scenario, "controller": OPTIMAL,
                "status": opt.status, "message": opt.message,
                **{k: (_num(v) if isinstance(v, float) else v) for k, v in f.items()},
            })
            for r in case_rows:
                r["time_ratio"] = _ratio(r.get("time_to_goal_s"), f.get("time_to_goal_s"))
                r["path_ratio"] = _ratio(r.get("path_length_m"), f.get("path_length_m"))
                r["energy_ratio"] = _ratio(r.get("energy_positive_j"),
                                           f.get("energy_positive_j"))
                r["effort_ratio"] = _ratio(r.get("torque_sq_integral_n2m2s"),
                                           f.get("torque_sq_integral_n2m2s"))
        rows.extend({k: r.get(k) for k in FIELDS} for r in case_rows)
    return rows


@dataclass(frozen=True)
class BenchmarkRequest:
    """A benchmark, as ``wmr benchmark`` asks for it; errors name its fields (``controllers``,
    ``tuned``, ``out``), the command line its options.

    Attributes
    ----------
    scenarios
        Scenario names or TOML files (default :data:`DEFAULT_SCENARIOS`).
    out
        The folder of the tables and logs (default ``runs/benchmark``).
    controllers
        Row labels (:func:`controller_row`; default :data:`CONTROLLERS`).
    tuned
        A ``wmr tune --save`` file of tuned gains (default: the declared ones).
    optimal
        Also solve and replay the optimum of each case.
    limit_cases
        Only the first N cases.
    fmi, fmu
        The project's FMI 2 or 3 build, or another robot FMU.
    """

    scenarios: Sequence[str] = ()
    out: str | Path | None = None
    controllers: Sequence[str] = ()
    tuned: str | Path | None = None
    optimal: bool = True
    limit_cases: int | None = None
    fmi: int = 3
    fmu: str | Path | None = None


@dataclass(frozen=True)
class BenchmarkOutcome:
    """What :func:`benchmark_command` made: the rows, the folder and its two tables."""

    rows: list[dict[str, Any]]
    out: Path
    tables: tuple[Path, Path]


def benchmark_command(request: BenchmarkRequest,
                      progress: Callable[[int, str, str], None] | None = None
                      ) -> BenchmarkOutcome:
    """What ``wmr benchmark`` does: check the request, run every case by every row's
    controller on one FMU (:func:`run_benchmark`) and write the tables (:func:`write_tables`).

    ``progress(runs, case, label)`` is told before each run, ``runs`` the number of them.
    """
    from wmr.apps.run import default_fmu
    from wmr.infra.outputs import check_output

    r = request
    out = check_output(r.out if r.out else Path("runs") / "benchmark", "out", "dir")
    specs = benchmark_specs(list(r.scenarios) or list(DEFAULT_SCENARIOS))
    if r.limit_cases is not None:
        specs = specs[: r.limit_cases]
    labels = list(r.controllers) or list(CONTROLLERS)
    tuned = load_tuned(r.tuned)
    for label in labels:  # before the FMU: an unknown row fails fast
        controller_row(label, tuned)
    runs = len(specs) * (len(labels) + (1 if r.optimal else 0))
    with FmuPlant(Path(r.fmu) if r.fmu else default_fmu(r.fmi)) as plant:
        rows = run_benchmark(specs, plant, out, labels, tuned, optimal=r.optimal,
                             progress=None if progress is None
                             else lambda case, label: progress(runs, case, label))
    return BenchmarkOutcome(rows, out, write_tables(rows, out))


def write_tables(rows: Sequence[Mapping[str, Any]], out_dir: Path) -> tuple[Path, Path]:
    """``benchmark.csv`` and ``benchmark.parquet`` in ``out_dir``; returns their paths."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = out_dir / "benchmark.csv"
    with csv_path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(FIELDS))
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in FIELDS})
    cols: dict[str, list[Any]] = {k: [r.get(k) for r in rows] for k in FIELDS}
    schema = pa.schema([(k, pa.string() if k in ("case", "scenario", "controller", "status",
                                                  "message", "mcap") else pa.float64())
                        for k in FIELDS])
    pq_path = out_dir / "benchmark.parquet"
    pq.write_table(pa.table(cols, schema=schema), pq_path)
    return csv_path, pq_path


def _fmt(v: Any, digits: int = 2) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def summary(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per controller: converged count, means of time, ratios, path, energy, effort, worst
    heading error."""
    out = []
    labels = list(dict.fromkeys(r["controller"] for r in rows))
    for label in labels:
        rs = [r for r in rows if r["controller"] == label]
        ok = [r for r in rs if r["status"] in ("converged", "solved")]

        def mean(key: str, rs_: Sequence[Mapping[str, Any]] = ok) -> float | None:
            vals = [r[key] for r in rs_ if r.get(key) is not None]
            return float(np.mean(vals)) if vals else None

        heads = [r["final_heading_error_rad"] for r in ok
                 if r.get("final_heading_error_rad") is not None]
        ratios = [r["time_ratio"] for r in ok if r.get("time_ratio") is not None]
        out.append({
            "controller": label, "ok": len(ok), "runs": len(rs),
            "mean_time_s": mean("time_to_goal_s"), "mean_time_ratio": mean("time_ratio"),
            "max_time_ratio": max(ratios) if ratios else None,
            "mean_path_m": mean("path_length_m"), "mean_path_ratio": mean("path_ratio"),
            "mean_energy_abs_j": mean("energy_abs_j"),
            "mean_effort_n2m2s": mean("torque_sq_integral_n2m2s"),
            "max_heading_error_deg": math.degrees(max(heads)) if heads else None,
        })
    return out


def format_tables(rows: Sequence[Mapping[str, Any]]) -> str:
    """Two text tables: time to goal per case and controller (with PI/optimal), and the
    summary per controller."""
    labels = list(dict.fromkeys(r["controller"] for r in rows))
    cases = list(dict.fromkeys(r["case"] for r in rows))
    by = {(r["case"], r["controller"]): r for r in rows}
    has_opt = OPTIMAL in labels
    head = ["case", *labels] + (["PI/opt"] if has_opt and "pi" in labels else [])
    lines = ["time to goal, s (* = not converged / not solved)",
             " | ".join(head), " | ".join("---" for _ in head)]
    for c in cases:
        cells = [c]
        for lab in labels:
            r = by.get((c, lab))
            if r is None:
                cells.append("")
                continue
            ok = r["status"] in ("converged", "solved")
            cells.append(_fmt(r["time_to_goal_s"]) if ok else f"*{r['status']}")
        if len(head) > len(cells):
            pr = by.get((c, "pi"))
            cells.append(_fmt(pr.get("time_ratio") if pr else None))
        lines.append(" | ".join(cells))
    lines.append("")
    s = summary(rows)
    sh = ["controller", "ok/runs", "mean time s", "time/opt mean", "time/opt max",
          "mean path m", "path/opt", "mean ∫|τω| J", "mean ∫τ² N²m²s", "max heading err °"]
    lines += ["summary", " | ".join(sh), " | ".join("---" for _ in sh)]
    for r in s:
        lines.append(" | ".join([
            r["controller"], f"{r['ok']}/{r['runs']}", _fmt(r["mean_time_s"]),
            _fmt(r["mean_time_ratio"], 3), _fmt(r["max_time_ratio"], 3), _fmt(r["mean_path_m"]),
            _fmt(r["mean_path_ratio"], 3), _fmt(r["mean_energy_abs_j"], 1),
            _fmt(r["mean_effort_n2m2s"], 0), _fmt(r["max_heading_error_deg"], 3)]))
    return "\n".join(lines)


__all__ = [
    "CONTROLLERS",
    "DEFAULT_SCENARIOS",
    "FIELDS",
    "OPTIMAL",
    "TUNED_SUFFIX",
    "BenchmarkOutcome",
    "BenchmarkRequest",
    "OptimalRun",
    "benchmark_command",
    "benchmark_specs",
    "controller_row",
    "controller_rows",
    "format_tables",
    "load_tuned",
    "optimal_metadata",
    "replay_figures",
    "run_benchmark",
    "run_logged",
    "run_optimal",
    "summary",
    "write_optimal_log",
    "write_tables",
]

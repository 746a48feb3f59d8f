"""One closed-loop co-simulation of the paper's stabiliser on the FMU, logged to MCAP.

This is the main job (``wmr run``) and the unit of work of a batch: it ties a
:class:`~wmr.config.scenario.RunSpec`, the FMU (:class:`~wmr.adapters.fmi.robot.FmuPlant`), the
master loop (:func:`~wmr.core.closedloop.run_closed_loop`) and the log
(:class:`~wmr.adapters.mcap.RunLogWriter`).
"""

from __future__ import annotations

import json
import math
import os
import sys
import zipfile
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

from wmr import __version__
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import RunLogWriter
from wmr.config.scenario import RunSpec
from wmr.config.scenario_file import run_spec_toml
from wmr.core.closedloop import BlockSink, Progress, run_closed_loop
from wmr.infra.paths import safe_filename

if TYPE_CHECKING:
    from wmr.adapters.fmi.controller import FmuController


def _notice(message: str) -> None:
    """A build that a run starts reports its steps on stderr (stdout is for results,
    ``--json``)."""
    print(f"wmr: {message}", file=sys.stderr, flush=True)


def default_fmu(fmi_version: int = 3) -> Path:
    """The FMU of the project's model, built (or reused) in the user's cache for this machine
    only (seconds with gcc; ``wmr fmu build`` builds every platform)."""
    from wmr.build.fmus import build_fmus

    return build_fmus(on_build=_notice, platforms="host").fmus[fmi_version]


def default_controller_fmu(fmi_version: int = 3) -> Path:
    """The controller FMU (the PI stabiliser in C), built (or reused) in the user's cache for
    this machine only."""
    from wmr.build.fmus import build_fmus

    return build_fmus(on_build=_notice, platforms="host").controllers[fmi_version]


def _jsonable(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def run_metadata(spec: RunSpec, plant: FmuPlant,
                 controller_fmu: FmuController | None = None) -> dict[str, object]:
    """The ``run`` metadata record of a log (``docs/formats.md``); ``sensors`` only when on, the
    controller FMU only when it ran the law, ``fmu_map`` for a mapped robot FMU."""
    extra: dict[str, object] = {} if controller_fmu is None else {
        "controller_fmu_file": controller_fmu.fmu_path.name,
        "controller_fmu_sha256": controller_fmu.sha256}
    meta: dict[str, object] = {
        "name": spec.name,
        "scenario": spec.scenario,
        "start": asdict(spec.start),
        "goal": asdict(spec.goal),
        "params": spec.params.as_dict(),
        "gains": spec.gains.as_dict(),
        "controller": spec.controller,
        "controller_gains": dict(spec.controller_gains),
        "limits": spec.limits.as_dict(),
        "control_period_s": spec.period_s,
        "stop_radius_m": spec.stop_radius_m,
        "heading_tolerance_rad": spec.heading_tolerance_rad,
        "max_time_s": spec.t_max_s,
        "fmu_sha256": plant.sha256,
        "fmu_file": plant.fmu_path.name,
        "fmi_version": plant.fmi_version,
        "software_version": f"wmr-cosim {__version__}",
        **extra,
    }
    if spec.sensors is not None:
        meta["sensors"] = spec.sensors.as_dict()
    var_map = getattr(plant, "var_map", None)  # test doubles of a plant have none
    if var_map is not None:
        meta["fmu_map"] = var_map.as_dict()
    return meta


def scenario_attachment_name(spec: RunSpec) -> str:
    """Name of the effective scenario a run's log attaches: ``NAME.toml``."""
    return f"{safe_filename(spec.name)}.toml"


def _attachments(spec: RunSpec, plant: FmuPlant) -> dict[str, tuple[str, bytes]]:
    """The FMU's ``modelDescription.xml`` and the run's effective scenario: the scenario file
    with every override of this run applied, one run only (a batch run's log holds its own
    run, not the whole spec), which ``wmr run`` reads back into the same run."""
    with zipfile.ZipFile(plant.fmu_path) as zf:
        md = zf.read("modelDescription.xml")
    return {"modelDescription.xml": ("application/xml", md),
            scenario_attachment_name(spec): ("application/toml",
                                             run_spec_toml(spec).encode("utf-8"))}


def run_to_log(spec: RunSpec, mcap_path: str | os.PathLike[str], plant: FmuPlant, *,
               scenario_file: Path | None = None,
               progress: Progress | None = None,
               also: BlockSink | None = None,
               controller_fmu: FmuController | None = None,
               durable: bool = True) -> dict[str, Any]:
    """Run ``spec`` on ``plant`` and log it to ``mcap_path``; return the result record.

    The log attaches the run's effective scenario (:func:`scenario_attachment_name`), not
    ``scenario_file``, whose name only is recorded in the ``run`` metadata (``source_file``).

    The log is written as the run goes, to ``mcap_path + ".partial"``, and renamed into place
    when finished (fsynced first unless ``durable`` is false): a run killed midway leaves the
    previous log whole and its own readable up to its last chunk in the ``.partial`` file
    (without a ``result`` record).  A run that fails is logged with status ``failed`` and its
    error, and the file is closed and readable.  ``also`` receives the same blocks as the log
    (the live Rerun view of ``wmr run --view``).  ``controller_fmu`` runs the controller FMU
    in place of the Python controller (``wmr run --controller-fmu``).

    Returns
    -------
    dict
        The fields of ``wmr run --json``: ``status`` (``converged``, ``timeout``, ``failed``),
        ``message``, ``final_position_error_m``, ``final_heading_error_rad``,
        ``time_to_goal_s``, ``path_length_m``, ``mcap``, the energy and torque figures, and
        ``estimated_final_position_error_m``, ``estimated_final_heading_error_rad``: the errors
        the stabiliser believed (the ``final_*`` ones are the true errors; the two agree
        without sensors).
    """
    path = Path(mcap_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    goal = (spec.goal.x_m, spec.goal.y_m, spec.goal.heading_rad)
    run = run_metadata(spec, plant, controller_fmu)
    if scenario_file is not None:
        run["source_file"] = Path(scenario_file).name
    with RunLogWriter(path, run=run, goal=goal, attachments=_attachments(spec, plant),
                      durable=durable) as log:
        sink: BlockSink = log
        if also is not None:
            from wmr.adapters.rerun.live_view import TeeSink

            sink = TeeSink(log, also)
        result = run_closed_loop(spec, plant, sink=sink, progress=progress,
                                 controller_fmu=controller_fmu)
        record: dict[str, Any] = {
            "name": spec.name,
            "status": result.status,
            "message": result.message,
            "final_position_error_m": _jsonable(result.final_position_error_m),
            "final_heading_error_rad": _jsonable(result.final_heading_error_rad),
            "time_to_goal_s": _jsonable(result.time_to_goal_s),
            "path_length_m": _jsonable(result.path_length_m),
            "energy_net_j": _jsonable(result.energy_net_j),
            "energy_positive_j": _jsonable(result.energy_positive_j),
            "energy_abs_j": _jsonable(result.energy_abs_j),
            "torque_sq_integral_n2m2s": _jsonable(result.torque_sq_integral),
            "peak_torque_nm": _jsonable(result.peak_torque_nm),
            "steps": result.steps,
            "estimated_final_position_error_m":
                _jsonable(result.estimated_final_position_error_m),
            "estimated_final_heading_error_rad":
                _jsonable(result.estimated_final_heading_error_rad),
            "mcap": str(path),
        }
        if result.sensing is not None:
            from wmr.adapters.mcap.sensing import write_sensing

            write_sensing(log, result.sensing)
        log.close(record)
    return record


def result_json(record: dict[str, Any]) -> str:
    """One line of JSON (NaN-free: non-finite figures are ``null``)."""
    return json.dumps(record, allow_nan=False, sort_keys=False)



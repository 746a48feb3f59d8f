"""One closed-loop co-simulation of the paper's stabiliser on the FMU, logged to MCAP.

This is the main job (``wmr run``) and the unit of work of a batch: it ties a
:class:`~wmr.core.runspec.RunSpec`, the FMU (:class:`~wmr.adapters.fmi.robot.FmuPlant`), the
master loop (:func:`~wmr.core.closedloop.run_closed_loop`) and the log, through the log
protocol (:mod:`wmr.core.runlog`; MCAP by default: :class:`~wmr.adapters.mcap.McapOpener`).
"""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import numpy.typing as npt

from wmr.adapters.fmi.compiled_law import CompiledLawController
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import McapOpener
from wmr.apps.request import RunRequest
from wmr.config.scenario_file import run_spec_toml
from wmr.core.closedloop import BlockSink, Controller, Progress, run_closed_loop
from wmr.core.plant import Pose
from wmr.core.record import result_record
from wmr.core.runlog import LogHeader, LogOpener, RunLog
from wmr.core.runspec import RunSpec
from wmr.infra.errors import ConfigError
from wmr.infra.paths import safe_filename
from wmr.infra.version import __version__

if TYPE_CHECKING:
    from wmr.adapters.fmi.controller import FmuController
    from wmr.config.scenario import Scenario


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


def _attachments(spec: RunSpec, plant: FmuPlant) -> tuple[tuple[str, str, bytes], ...]:
    """The FMU's ``modelDescription.xml`` and the run's effective scenario: the scenario file
    with every override of this run applied, one run only (a batch run's log holds its own
    run, not the whole spec), which ``wmr run`` reads back into the same run."""
    return (("modelDescription.xml", "application/xml", plant.model_description_xml),
            (scenario_attachment_name(spec), "application/toml",
             run_spec_toml(spec).encode("utf-8")))


#: What a log policy keeps: every run's log, the logs of the runs that did not converge
#: (``failed`` and ``timeout``), or none (the result record alone).
LOG_KEEPS: Final = ("full", "failed", "none")
#: Rows of a run that a ``failed`` policy holds in memory before it starts writing its log
#: (264 bytes a row, the time and 32 signals: 26 MB, a 1000 s run at 100 Hz); a longer run
#: is written to its ``.partial`` file from there on, and removed if it converges.
HOLD_ROWS: Final = 100_000


@dataclass(frozen=True)
class LogPolicy:
    """Which runs keep a log, and how much of it (``docs/batch.md``).

    Attributes
    ----------
    keep
        ``"full"`` (every run), ``"failed"`` (the runs that did not converge: ``failed`` and
        ``timeout``) or ``"none"`` (no log: the result record is all).
    every_k_steps
        Log every k-th control step (and the last); 1 logs every step.
    """

    keep: str = "full"
    every_k_steps: int = 1

    def __post_init__(self) -> None:
        if self.keep not in LOG_KEEPS:
            raise ConfigError("log.keep", f"unknown policy {self.keep!r}",
                              f"use one of: {', '.join(LOG_KEEPS)}")
        k = self.every_k_steps
        if isinstance(k, bool) or not isinstance(k, int) or k < 1:
            raise ConfigError("log.every_k_steps", f"must be an integer >= 1, got {k!r}",
                              "give e.g. every_k_steps = 10, or 1 for every step")

    def keeps(self, status: str) -> bool:
        """Whether a run that ended with ``status`` keeps its log."""
        return self.keep == "full" or (self.keep == "failed" and status != "converged")

    def describe(self) -> str:
        """One phrase: ``"full logs"``, ``"logs of failed and timed-out runs, every 10th
        step"``, ``"no logs"``."""
        text = {"full": "full logs", "failed": "logs of failed and timed-out runs only",
                "none": "no logs"}[self.keep]
        if self.keep != "none" and self.every_k_steps > 1:
            text += f", every {self.every_k_steps}th control step"
        return text

    def as_dict(self) -> dict[str, object]:
        """The policy as ``batch.json`` and the ``[log]`` table of a spec write it."""
        return {"keep": self.keep, "every_k_steps": self.every_k_steps}


#: Every run keeps its whole log: the policy of ``wmr run`` and of small batches.
FULL_LOGS: Final = LogPolicy()


class _EveryK:
    """A sink that passes every k-th row (counted over the whole run) to any
    :class:`~wmr.core.closedloop.BlockSink` and, at :meth:`end`, the run's last row if it was
    not passed: a decimated log still ends where the run did."""

    def __init__(self, sink: BlockSink, k: int) -> None:
        self._sink, self._k = sink, k
        self._row = 0  # index of the next row in the run
        self._last: tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]] | None = None

    def write_block(self, t_ns: npt.NDArray[np.int64], block: npt.NDArray[np.float64]) -> None:
        n = len(t_ns)
        if not n:
            return
        first = -self._row % self._k  # the first row of this block on the k-grid
        self._sink.write_block(t_ns[first::self._k], block[first::self._k])
        self._row += n
        # the block's last row, unless it was passed (copied: the caller reuses its arrays)
        self._last = None if (n - 1 - first) % self._k == 0 and first < n else (
            t_ns[-1:].copy(), block[-1:].copy())

    def end(self) -> None:
        if self._last is not None:
            self._sink.write_block(*self._last)
            self._last = None


class _Held:
    """A sink that holds the run's rows in memory (a copy of each block, no encoding) until
    :meth:`spill` or :data:`HOLD_ROWS` rows, then writes them, and the rest, to the log that
    ``open_log`` opens (any :class:`~wmr.core.runlog.RunLog`): a run that converges under a
    ``failed`` policy costs a copy of its rows, not the encoding and compression of a log."""

    def __init__(self, open_log: Callable[[], RunLog]) -> None:
        self._open = open_log
        self._blocks: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]] = []
        self._rows = 0
        self.log: RunLog | None = None

    def write_block(self, t_ns: npt.NDArray[np.int64], block: npt.NDArray[np.float64]) -> None:
        if self.log is not None:
            self.log.write_block(t_ns, block)
            return
        self._blocks.append((t_ns.copy(), block.copy()))
        self._rows += len(t_ns)
        if self._rows >= HOLD_ROWS:
            self.spill()

    def spill(self) -> RunLog:
        """The log, opened now if it was not, with the rows held so far written to it (the
        bytes are those of a log written as the run went: chunks are cut by simulation time,
        not by how the rows arrive)."""
        if self.log is None:
            self.log = self._open()
            for t_ns, block in self._blocks:
                self.log.write_block(t_ns, block)
            self._blocks.clear()
        return self.log


def log_header(spec: RunSpec, plant: FmuPlant, controller_fmu: FmuController | None = None,
               scenario_file: Path | None = None, policy: LogPolicy = FULL_LOGS) -> LogHeader:
    """The header a run's log is opened with: :func:`run_metadata` (with ``source_file``,
    the name of ``scenario_file``, and ``log_every_k_steps`` of a decimating ``policy``), the
    goal, the attachments (:func:`scenario_attachment_name`) and the spec's robot and stop
    radius."""
    run = run_metadata(spec, plant, controller_fmu)
    if scenario_file is not None:
        run["source_file"] = Path(scenario_file).name
    if policy.every_k_steps > 1:
        run["log_every_k_steps"] = policy.every_k_steps
    return LogHeader.of_spec(spec, run, _attachments(spec, plant))


def run_to_log(spec: RunSpec, out: str | os.PathLike[str] | LogOpener, plant: FmuPlant, *,
               scenario_file: Path | None = None,
               progress: Progress | None = None,
               also: BlockSink | None = None,
               controller_fmu: FmuController | None = None,
               log: LogPolicy = FULL_LOGS,
               controller: Controller | None = None) -> dict[str, Any]:
    """Run ``spec`` on ``plant`` and log it; return the result record.

    ``out`` is where the log goes: a path (the MCAP log there, as
    :class:`~wmr.adapters.mcap.McapOpener` of that path opens it) or any
    :data:`~wmr.core.runlog.LogOpener` (an MCAP opener with other options: not fsynced,
    ``on_open``; an in-memory :class:`~wmr.core.runlog.MemoryOpener`; another format's).  It
    is called with the run's :func:`log_header` when the log is opened.

    The log attaches the run's effective scenario (:func:`scenario_attachment_name`), not
    ``scenario_file``, whose name only is recorded in the ``run`` metadata (``source_file``).

    An MCAP log is written as the run goes, to ``path + ".partial"``, and renamed into place
    when finished (fsynced first unless the opener's ``durable`` is false): a run killed
    midway leaves the previous log whole and its own readable up to its last chunk in the
    ``.partial`` file (without a ``result`` record).  A run that fails is logged with status
    ``failed`` and its error, and the log is closed and readable.  ``also`` receives the same
    blocks as the log (the live Rerun view of ``wmr run --view``).  ``controller_fmu`` runs
    the controller FMU in place of the Python controller (``wmr run --controller-fmu``);
    ``controller`` runs any other :class:`~wmr.core.closedloop.Controller` (default: the
    run's own law, :class:`~wmr.adapters.fmi.compiled_law.CompiledLawController`, which runs
    the paper's PI compiled into the C stepper with the Python law's bits, and any other law
    in Python).

    ``log`` decides whether a log is kept (:class:`LogPolicy`): with ``keep="failed"`` the
    rows are held in memory (up to :data:`HOLD_ROWS`) and written only if the run does not
    converge, with ``keep="none"`` never; with ``every_k_steps=k`` every k-th step and the
    last are logged, and the ``run`` record says ``log_every_k_steps``.  A run without a log
    opens none (nothing is written at an MCAP path; a log there from before is left alone)
    and its record's ``mcap`` is ``None``.

    Returns
    -------
    dict
        The fields of ``wmr run --json``: ``status`` (``converged``, ``timeout``, ``failed``),
        ``message``, ``final_position_error_m``, ``final_heading_error_rad``,
        ``time_to_goal_s``, ``path_length_m``, ``mcap`` (the log's location: ``None`` when no
        log was kept, or it is not a file), the energy and torque figures, and
        ``estimated_final_position_error_m``, ``estimated_final_heading_error_rad``: the
        errors the stabiliser believed (the ``final_*`` ones are the true errors; the two
        agree without sensors).
    """
    if controller is not None and controller_fmu is not None:
        raise ConfigError("controller", "both a controller and a controller FMU were given",
                          "give one of them")
    opener: LogOpener = out if callable(out) else McapOpener(Path(out))

    def open_log() -> RunLog:
        # the header when a log is opened, not before: a run that keeps none never makes it
        return opener(log_header(spec, plant, controller_fmu, scenario_file, log))

    with ExitStack() as stack:
        held: _Held | None = None
        writer: RunLog | None = None
        if log.keep == "full":
            writer = stack.enter_context(open_log())
        elif log.keep == "failed":
            held = _Held(open_log)

            def failed(exc_type: type[BaseException] | None, exc: BaseException | None,
                       tb: TracebackType | None) -> bool:
                # the run raised, so it failed: its log is kept, the error as its result
                if exc is not None and writer is None and held is not None:
                    held.spill().__exit__(exc_type, exc, tb)
                return False

            stack.push(failed)
        sink: BlockSink | None = writer if writer is not None else held
        thin = None
        if sink is not None and log.every_k_steps > 1:
            sink = thin = _EveryK(sink, log.every_k_steps)
        if also is not None:
            from wmr.adapters.rerun.live_view import TeeSink

            sink = also if sink is None else TeeSink(sink, also)
        law = controller or controller_fmu or CompiledLawController()
        result = run_closed_loop(spec, plant, sink=sink, progress=progress, controller=law)
        if thin is not None:
            thin.end()
        record = result_record(spec.name, result)
        if held is not None:
            if log.keeps(result.status):
                writer = stack.enter_context(held.spill())
            elif held.log is not None:  # a long run spilled, then converged: not kept
                held.log.discard(record)
                held.log = None
        if writer is None:
            record["mcap"] = None
            return record
        record["mcap"] = writer.location
        if result.sensing is not None:
            writer.write_sensing(result.sensing)
        writer.close(record)
    return record


def result_json(record: dict[str, Any]) -> str:
    """One line of JSON (NaN-free: non-finite figures are ``null``)."""
    return json.dumps(record, allow_nan=False, sort_keys=False)




#: Run names an error of :func:`select_run` lists before "...".
LISTED_RUNS = 20


def select_run(scenario: Scenario, name: str | None) -> RunSpec:
    """The run ``name`` of ``scenario``, or its only run; an error names the field ``run``."""
    from wmr.config.naming import name_list

    names = [r.name for r in scenario.runs]
    runs = [r for r in scenario.runs if name is None or r.name == name]
    if len(runs) == 1:
        return runs[0]
    problem = (f"scenario {scenario.name} has no run {name!r}" if name is not None
               else f"scenario {scenario.name} has {len(runs)} runs")
    # 20 names and the count (name_list): a scenario's runs are few, and a name cut short
    # cannot be given back as the run; all of them with their poses: wmr run SCENARIO --list
    raise ConfigError("run", problem, "pick one with run=NAME of "
                      f"{name_list(names, shown=LISTED_RUNS)}")


#: ``progress_bar(run_name)``: the progress callback of a run and what closes it.
ProgressBar = Callable[[str], tuple[Progress, Callable[[], None]]]


def _warn(field: str, message: str) -> None:
    _notice(f"warning: {field} {message}")


@dataclass(frozen=True)
class ResolvedRun:
    """What one run needs, resolved from a :class:`~wmr.apps.request.RunRequest`: every input
    checked, nothing built or opened yet."""

    spec: RunSpec
    scenario_file: Path | None
    log_path: Path
    policy: LogPolicy
    fmu_path: Path | None  # None: the project's own build for ``fmi`` (built when opened)
    fmu_map: Path | None
    controller_fmu: Path | None  # None: the law in Python (or compiled into the stepper)
    use_built_controller_fmu: bool
    fmi: int
    view_rrd: Path | None


def resolve_run(request: RunRequest,
                warn: Callable[[str, str], None] = _warn) -> ResolvedRun:
    """Load the request's scenario, pick its run, apply the overrides, name the run and its
    log, and check every input, before anything is built; ``warn(field, message)`` is told of
    inputs that run as given but look wrong (a heading in radians)."""
    from wmr.config.naming import default_log_path, fmu_tokens, run_name, variant_name
    from wmr.config.scenario import heading_looks_like_radians, load_scenario, with_overrides
    from wmr.infra.outputs import check_output

    o = request.overrides
    for name, pose in (("start", o.start), ("goal", o.goal)):
        if pose is None or isinstance(pose, Pose):  # a Pose's heading is in rad
            continue
        as_pi = heading_looks_like_radians(pose[2])
        if as_pi is not None:  # run as given (it may be meant), said
            warn(name, f"heading {pose[2]:g} is in degrees but looks like {as_pi} rad: give "
                       f"{math.degrees(pose[2]):.4g} if you meant {as_pi} rad")
    sc = load_scenario(request.scenario)
    base = select_run(sc, request.run)
    spec = with_overrides(base, o)
    choice = request.controller_fmu
    ctrl_choice = (None if choice is False else "" if choice is True
                   else spec.controller_fmu if choice is None else str(choice))
    # a variant is named after what it changes, so that its log never overwrites the
    # scenario's own run (runs/fig11.mcap) nor passes for it; the plant and controller
    # implementation (FMI version, another FMU, the controller FMU) name the log file only,
    # not the run, whose name seeds the sensor noise (the same run on another FMU is the same)
    extra = fmu_tokens(request.fmi, None if request.fmu is None else str(request.fmu))
    if request.fmu_map is not None:
        extra.append(f"map_{Path(request.fmu_map).stem}")
    if ctrl_choice is not None and base.controller_fmu is None:
        extra.append("controller_fmu")
    spec = replace(spec, name=run_name(base, spec))
    path = check_output(request.out if request.out is not None
                        else default_log_path(variant_name(spec.name, extra)),
                        "out", suffix=".mcap")
    view_rrd = check_output(path.with_suffix(".rrd"), "view") if request.view else None
    ctrl_path = None
    if ctrl_choice is not None:
        if spec.controller != "pi":
            raise ConfigError("controller_fmu", f"the controller FMU is the PI stabiliser, "
                              f"but the run uses controller = {spec.controller!r}",
                              "drop controller_fmu or run the pi controller")
        ctrl_path = Path(ctrl_choice) if ctrl_choice else None
        if ctrl_path is not None and not ctrl_path.is_file():
            raise ConfigError("controller_fmu", f"no such file: {ctrl_path}",
                              "give a controller .fmu, or none for the built one")
    return ResolvedRun(
        spec=spec, scenario_file=sc.path, log_path=path,
        policy=log_policy(request.log, request.log_every, None)
        or FULL_LOGS,
        fmu_path=Path(request.fmu) if request.fmu is not None else sc.fmu,
        fmu_map=Path(request.fmu_map) if request.fmu_map is not None else sc.fmu_map,
        controller_fmu=ctrl_path, use_built_controller_fmu=ctrl_choice == "",
        fmi=request.fmi, view_rrd=view_rrd)


def run_scenario(request: RunRequest, *, progress_bar: ProgressBar | None = None,
                 on_log: Callable[[Path, str], None] | None = None,
                 warn: Callable[[str, str], None] = _warn) -> tuple[dict[str, Any], RunSpec]:
    """One run of a scenario, as ``wmr run`` and :func:`wmr.run` make it: resolve the request
    (:func:`resolve_run`), open the FMUs, run and log.

    ``progress_bar(run_name)`` gives the run's progress callback and what closes it;
    ``on_log(path, run_name)`` is called once the log's ``.partial`` file is open (a
    supervising parent finishes it if this process dies: :mod:`wmr.apps.supervise`);
    ``warn`` is :func:`resolve_run`'s.

    Returns
    -------
    tuple
        The result record (``docs/results.md``) and the run's spec.
    """
    from wmr.adapters.fmi.varmap import load_map

    r = resolve_run(request, warn)
    var_map = load_map(r.fmu_map) if r.fmu_map is not None else None
    ctrl_path = default_controller_fmu(r.fmi) if r.use_built_controller_fmu else r.controller_fmu
    fmu_path = r.fmu_path or default_fmu(r.fmi)
    progress, finish = progress_bar(r.spec.name) if progress_bar is not None else (None, None)
    live = None
    if r.view_rrd is not None:
        from wmr.adapters.rerun.live_view import live_view_sink

        live = live_view_sink(r.spec.name, r.spec.goal, r.view_rrd, start=r.spec.start,
                              stop_radius_m=r.spec.stop_radius_m)
    with FmuPlant(fmu_path, var_map=var_map) as plant, ExitStack() as stack:
        ctrl = None
        if ctrl_path is not None:
            from wmr.adapters.fmi.controller import FmuController

            ctrl = stack.enter_context(FmuController(ctrl_path))
        try:
            name = r.spec.name
            opener = McapOpener(r.log_path, on_open=None if on_log is None
                                else lambda path: on_log(path, name))
            record = run_to_log(r.spec, opener, plant, scenario_file=r.scenario_file,
                                progress=progress, also=live, controller_fmu=ctrl,
                                log=r.policy)
        finally:
            if finish is not None:
                finish()
            if live is not None:
                live.close()
                print(f"live view recorded in {r.view_rrd}", file=sys.stderr)
    return record, r.spec


def log_policy(keep: str | None, every_k_steps: int | None,
               base: LogPolicy | None) -> LogPolicy | None:
    """The log policy of ``log`` and ``log_every`` over ``base`` (a spec's ``[log]``);
    ``None`` when neither input nor ``base`` names one."""
    if every_k_steps is not None and (isinstance(every_k_steps, bool)
                                      or not isinstance(every_k_steps, int)
                                      or every_k_steps < 1):
        raise ConfigError("log_every", f"must be >= 1, got {every_k_steps}",
                          "give e.g. log_every=10, or 1 for every step")
    if keep is None and every_k_steps is None:
        return base
    start = base or FULL_LOGS
    return LogPolicy(keep or start.keep, every_k_steps or start.every_k_steps)

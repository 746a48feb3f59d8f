"""The Python API for notebooks and scripts: ``import wmr``.

::

    import wmr
    res = wmr.run("fig11", params={"m": 40.0})    # a closed-loop run on the FMU, logged
    res.path                                       # DataFrame: t_s, x_m, y_m, theta_rad
    log = wmr.read_log(res.mcap)                   # every signal as a DataFrame + metadata

Every function runs what the matching command runs (``wmr run``, ``wmr batch``, ``wmr
optimal``) with the same names, validation, logs and result records (``docs/results.md``);
results show as a table in a notebook (``_repr_html_``) and draw themselves (``plot()``).

Signals come as :class:`pandas.DataFrame` s: pandas is what notebooks, matplotlib and seaborn
take as they are, and the batch summaries are Arrow tables that become DataFrames without a
copy of the columns' meaning.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from wmr.infra.errors import ConfigError

if TYPE_CHECKING:  # pandas and matplotlib load only when a result is used
    import pandas as pd
    from matplotlib.axes import Axes

    from wmr.adapters.rerun.replay import ReplayResult
    from wmr.config.scenario import Scenario

PoseLike = Sequence[float]


def _not_in_a_worker_import(function: str) -> None:
    """Stop, in one line, a script that calls the API at its top level from running again in
    every batch worker: multiprocessing's workers import the script (as ``__mp_main__``) to
    find its functions, and its unguarded calls would repeat its runs and start a batch inside
    the batch."""
    import sys

    # multiprocessing runs the script under the name __mp_main__ in each worker
    # (runpy.run_path), while __main__ is still the worker's own; in the parent, __mp_main__
    # is only another name of __main__
    imported = sys.modules.get("__mp_main__")
    script = getattr(imported, "__file__", None)
    if getattr(imported, "__name__", None) == "__mp_main__" and script is not None:
        # printed here: a forkserver child ends with os._exit, which drops SystemExit's text
        print(f"wmr: error: {script} calls wmr.{function} at its top level, and batch "
              "workers import the script again: put its code under "
              "`if __name__ == \"__main__\":` (docs/api.md)", file=sys.stderr, flush=True)
        raise SystemExit(1)


#: Columns of :attr:`Log.path` (and :attr:`RunResult.path`).
PATH_COLUMNS = ("x_m", "y_m", "theta_rad")


def _table_html(title: str, record: Mapping[str, Any]) -> str:
    rows = "".join(
        f"<tr><th style='text-align:left'>{html.escape(str(k))}</th>"
        f"<td style='text-align:left'>{html.escape(_fmt(v))}</td></tr>"
        for k, v in record.items() if not isinstance(v, dict))
    return f"<b>{html.escape(title)}</b><table>{rows}</table>"


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.6g}" if math.isfinite(v) else "-"
    return "-" if v is None else str(v)


@dataclass(frozen=True)
class Log:
    """A run log read back (:func:`read_log`).

    Attributes
    ----------
    path_to_file
        The ``.mcap`` file.
    signals
        One row per control step, index ``t_s`` (simulation time, s), a column per signal of
        :data:`wmr.core.signals.SIGNALS` (name with unit; NaN where the log has no such topic).
    metadata
        ``run`` and ``result`` records, values decoded from JSON.
    attachments
        Attachment name -> bytes (the effective scenario ``NAME.toml``, the FMU's
        ``modelDescription.xml``).
    truncated, warnings
        A cut file's prefix, and what was skipped.
    phase
        The control phase at each row of ``signals`` (same index, name ``phase``): 0.0
        approach, 1.0 align (the stabiliser's final turn inside the stop radius), from the
        logged ``/controller/phase``; None when the log has none (a killed run before
        ``wmr log recover``, an open-loop or optimal run, a log of another program).
    """

    path_to_file: Path
    signals: pd.DataFrame
    metadata: dict[str, dict[str, Any]]
    attachments: dict[str, bytes] = field(default_factory=dict)
    truncated: bool = False
    warnings: tuple[str, ...] = ()
    phase: pd.Series | None = None

    @property
    def path(self) -> pd.DataFrame:
        """The robot's path: ``x_m``, ``y_m``, ``theta_rad`` against ``t_s``."""
        return self.signals[list(PATH_COLUMNS)]

    @property
    def result(self) -> dict[str, Any]:
        """The ``result`` record (the ``wmr run --json`` object)."""
        return self.metadata.get("result", {})

    @property
    def scenario_toml(self) -> str | None:
        """The effective scenario attached to the log (``wmr run`` repeats the run from it)."""
        for name, data in self.attachments.items():
            if name.endswith(".toml"):
                return data.decode("utf-8")
        return None

    def plot(self, ax: Axes | None = None) -> Axes:
        """Draw the path of B and the goal in the plane (m), equal axes."""
        return _plot_path(self.path, self.metadata.get("run", {}).get("goal"),
                          str(self.metadata.get("run", {}).get("name", "")), ax)

    def _repr_html_(self) -> str:
        name = self.metadata.get("run", {}).get("name", self.path_to_file.name)
        return _table_html(f"{name}: {len(self.signals)} steps, {self.path_to_file}",
                           self.result)


def _plot_path(path: pd.DataFrame, goal: Mapping[str, float] | None, label: str,
               ax: Axes | None) -> Axes:
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots()
    ax.plot(path["x_m"], path["y_m"], label=label or None)
    if goal:
        ax.plot([goal["x_m"]], [goal["y_m"]], "k*", markersize=12, label="goal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best")
    return ax


def read_log(path: str | Path, pose_topic: str | None = None,
             signals: Sequence[str] | None = None) -> Log:
    """Read a run log (``wmr run``, ``wmr batch``, ``wmr optimal``) into a :class:`Log`.

    A log of poses only (a real robot's: ``foxglove.PoseInFrame`` or
    ``foxglove.FrameTransform`` messages, found by schema name, or on ``pose_topic``) gives
    ``x_m``, ``y_m`` and ``theta_rad`` (the yaw of its quaternions), from its first pose,
    every other signal NaN, and a warning saying it is a pose-only log.  A log of ours is
    read as ours whatever ``pose_topic`` says.

    ``signals`` (names of :data:`wmr.core.signals.SIGNALS`; default: all) are the columns of
    ``Log.signals``: only the topics that carry them are read and decoded (the path, ``x_m``,
    ``y_m``, ``theta_rad``, is ``/robot/state`` alone), in less time and memory.

    Raises
    ------
    wmr.infra.errors.LogError
        The file is missing, not a regular file, or not MCAP (one line naming it); a damaged
        or hostile log is read within limits, with ``truncated`` and ``warnings`` set.
    wmr.infra.errors.ConfigError
        ``signals`` names a signal that is not one of ``SIGNALS``.
    """
    import pandas as pd

    from wmr.adapters.mcap import read_run
    from wmr.adapters.mcap.reader import metadata_json
    from wmr.infra.errors import LogError

    data = read_run(path, pose_topic=pose_topic, signals=signals)
    # the columns are read_run's own arrays: the frame takes them without a copy
    frame = pd.DataFrame(data.signals, index=pd.Index(data.t_s, name="t_s"), copy=False)
    metadata: dict[str, dict[str, Any]] = {}
    warnings = list(data.warnings)
    for rec, values in data.metadata.items():
        decoded: dict[str, Any] = {}
        for k, v in values.items():
            try:
                decoded[k] = metadata_json(v)
            except ValueError:  # not JSON: a plain string
                decoded[k] = v
            except LogError as exc:  # too large or too deep to decode safely
                decoded[k] = v
                warnings.append(f"metadata {rec}.{k} kept as text: {exc}")
        metadata[rec] = decoded
    phase = (None if data.phase is None
             else pd.Series(data.phase, index=frame.index, name="phase"))
    return Log(Path(path), frame, metadata, dict(data.attachments), data.truncated,
               tuple(warnings), phase)


#: ``RunResult``'s log not read yet: it is read from ``record["mcap"]`` when first asked.
_UNREAD: Any = object()


class RunResult:
    """A run made by :func:`run` or :func:`optimal`: its result record and its log.

    The log is read from its file (``record["mcap"]``) when :attr:`log`, :attr:`signals` or
    :meth:`plot` first needs it, not when the run ends: a long run costs the notebook what it
    costs ``wmr run`` (no frame of every step held in memory) until its signals are asked
    for.  :attr:`path` alone reads the path alone (``/robot/state``), unless the log was read.
    """

    __slots__ = ("_log", "_path", "record")

    def __init__(self, record: dict[str, Any], log: Log | None = _UNREAD) -> None:
        self.record = record
        self._log = log
        self._path: pd.DataFrame | None = None

    @property
    def log(self) -> Log | None:
        """The run's log (:class:`Log`), read on first use; None when nothing was logged."""
        if self._log is _UNREAD:
            mcap = self.record.get("mcap")
            self._log = read_log(mcap) if mcap else None
        return self._log

    def __repr__(self) -> str:
        return f"RunResult(record={self.record!r}, mcap={self.mcap!r})"

    @property
    def status(self) -> str:
        """``converged``, ``timeout`` or ``failed`` (optimal: ``solved``, ``infeasible``...)."""
        return str(self.record["status"])

    @property
    def mcap(self) -> Path | None:
        """The log file (None when nothing was logged)."""
        return None if self.record.get("mcap") is None else Path(self.record["mcap"])

    @property
    def path(self) -> pd.DataFrame:
        """The robot's path: ``x_m``, ``y_m``, ``theta_rad`` against ``t_s``.

        Without a log (``log="none"``, or ``log="failed"`` and a run that did not fail) it is
        empty, and a :class:`UserWarning` says so and how to get the path: an empty frame
        alone read as a run that never moved.
        """
        if self._log is _UNREAD and self.record.get("mcap"):
            if self._path is None:  # the path's topic only, kept
                self._path = read_log(self.record["mcap"], signals=PATH_COLUMNS).path
            return self._path
        if self.log is None:
            import warnings

            import pandas as pd

            warnings.warn(
                f"run {self.record.get('name', '')!r} wrote no log (log=\"none\", or "
                "log=\"failed\" and the run did not fail), so its .path is empty: run it "
                "again with log=\"full\" (the default) to get the path", stacklevel=2)
            return pd.DataFrame(columns=list(PATH_COLUMNS), index=pd.Index([], name="t_s"))
        return self.log.path

    @property
    def signals(self) -> pd.DataFrame:
        """Every signal of the log (:attr:`Log.signals`)."""
        if self.log is None:
            raise ConfigError("log", "this run wrote no log", "see .record['message']")
        return self.log.signals

    def __getitem__(self, key: str) -> Any:
        return self.record[key]

    def plot(self, ax: Axes | None = None) -> Axes:
        """Draw the path and the goal (:meth:`Log.plot`)."""
        if self.log is None:
            raise ConfigError("log", "this run wrote no log", "see .record['message']")
        return self.log.plot(ax)

    def _repr_html_(self) -> str:
        return _table_html(str(self.record.get("name", "run")), self.record)


def load_scenario(name_or_path: str | Path | None = None) -> Scenario:
    """A scenario file (``"fig9"``, ``"fig10"``, ``"fig11"`` or a path), validated and
    expanded (:func:`wmr.config.scenario.load_scenario`)."""
    from wmr.config.scenario import load_scenario as _load

    return _load(name_or_path)


def run(scenario: str | Path | None = None, *, run: str | None = None,
        start: PoseLike | None = None, goal: PoseLike | None = None,
        params: Mapping[str, float] | None = None, gains: Mapping[str, float] | None = None,
        limits: Mapping[str, float] | None = None, period_s: float | None = None,
        stop_radius_m: float | None = None, max_time_s: float | None = None,
        controller: str | None = None, controller_gains: Mapping[str, float] | None = None,
        sensors: str | None = None, sensor: Mapping[str, float | str] | None = None,
        controller_fmu: bool | str | Path | None = None, out: str | Path | None = None,
        fmi: int = 3, fmu: str | Path | None = None, fmu_map: str | Path | None = None,
        log: str | None = None, log_every: int | None = None,
        view: bool = False) -> RunResult:
    """One closed-loop run, as ``wmr run`` makes it (the same function runs both:
    :func:`wmr.apps.run.run_scenario`); returns its record and its log.

    Parameters
    ----------
    scenario
        Scenario name or file (default ``fig11``); ``run`` picks one run of a multi-run one.
    start, goal
        ``(x_m, y_m, heading_deg)``, as on the command line.
    params, gains, limits
        Overrides by name (``--param``, ``--gain``, ``--limit``).
    period_s, stop_radius_m, max_time_s, controller, controller_gains
        Overrides of the run's settings (``--period``, ``--stop-radius``, ``--max-time``; the
        scenario keys ``controller`` and ``[controller_gains]``): ``controller`` any name of
        :mod:`wmr.core.control.registry`, an installed plug-in's too (``docs/plugins.md``),
        ``controller_gains`` the gains it declares.
    sensors, sensor
        ``--sensors``: a preset (``"gps"``, ``"raw"``) or ``"off"``; ``--sensor``: fields of
        the ``[sensors]`` table over it, e.g. ``{"gps_sigma_m": 0.05}`` (``docs/sensing.md``).
    controller_fmu
        ``--controller-fmu``: ``True`` runs the law in the built controller FMU, a path in
        that FMU; ``False`` runs the Python law although the scenario names an FMU; ``None``
        (default): as the scenario says.
    out
        The log (default ``runs/NAME.mcap``, NAME after the overrides: ``docs/results.md``).
    fmi, fmu, fmu_map
        The project's FMI 2 or 3 build, or another FMU file and its variable map
        (``--map``, ``docs/fmu_map.md``); default: the scenario's ``fmu`` and ``fmu_map``.
    log, log_every
        ``--log`` (``"full"``, ``"failed"``, ``"none"``) and ``--log-every`` K.
    view
        ``--view``: show the run live in Rerun and save it as ``NAME.rrd`` next to the log.
    """
    _not_in_a_worker_import("run")
    from wmr.apps.request import Overrides, RunRequest
    from wmr.apps.run import run_scenario

    overrides = Overrides(start=start, goal=goal, params=params, gains=gains, limits=limits,
                          period_s=period_s, stop_radius_m=stop_radius_m,
                          max_time_s=max_time_s, controller=controller,
                          controller_gains=controller_gains, sensors=sensors, sensor=sensor)
    record, _ = run_scenario(RunRequest(scenario, run=run, overrides=overrides,
                                        controller_fmu=controller_fmu, fmi=fmi, fmu=fmu,
                                        fmu_map=fmu_map, out=out, log=log,
                                        log_every=log_every, view=view))
    return RunResult(record)


def optimal(start: PoseLike | None = None, goal: PoseLike | None = None, *,
            objective: str = "time", torque_limit_nm: float | None = None,
            torque_only: bool = False, final_time_s: float | None = None,
            period_s: float = 0.01, out: str | Path | None = None,
            fmi: int = 3, fmu: str | Path | None = None, scenario: str | Path | None = None,
            run: str | None = None, params: Mapping[str, float] | None = None,
            limits: Mapping[str, float] | None = None) -> RunResult:
    """The optimal manoeuvre, as ``wmr optimal`` makes it (solved, replayed on the FMU,
    logged); ``start`` and ``goal`` are ``(x_m, y_m, heading_deg)`` (default ``(0, 0, 0)`` and
    ``(20, 10, 0)``), or those of the run
    ``run`` of ``scenario`` (a name or TOML file, as :func:`run` takes it); ``params`` and
    ``limits`` replace the robot's parameters and the limits by name (``{"m": 40.0}``).

    Both check their inputs, name the case and its log in
    :func:`wmr.apps.optimal.optimal_command`: the same one-line errors, naming the keyword
    here (``final_time_s``) where the command names the option (``--final-time``).
    """
    _not_in_a_worker_import("optimal")
    from wmr.apps.optimal import OptimalRequest, optimal_command
    from wmr.apps.request import Overrides

    record = optimal_command(OptimalRequest(
        scenario, run=run,
        overrides=Overrides(start=start, goal=goal, params=params, limits=limits),
        objective=objective, torque_limit_nm=torque_limit_nm, torque_only=torque_only,
        final_time_s=final_time_s, period_s=period_s, out=out, fmi=fmi, fmu=fmu))
    return RunResult(record)


@dataclass(frozen=True)
class BatchResult:
    """A batch made by :func:`batch`: its folder and its summary, one row per run."""

    out: Path
    summary: pd.DataFrame

    def log(self, run_id: str, *, rerun: bool = False) -> Log:
        """The log of one run of the batch, wherever the batch kept it (the summary's ``mcap``
        column: ``runs/<run_id>.mcap``, or ``runs/<shard>/<run_id>.mcap`` in a batch of over
        1000 runs).

        Parameters
        ----------
        run_id
            The run's id (the summary's ``run_id``).
        rerun
            For a run whose log the batch's log policy did not keep: make the run again with
            a full log (as ``wmr rerun DIR RUN_ID`` does, into ``DIR/rerun/<run_id>.mcap``)
            and return that log.

        Raises
        ------
        ConfigError
            No such run in the summary, or its log was not kept (and ``rerun`` is False).
        """
        rows = self.summary.loc[self.summary["run_id"] == run_id, "mcap"]
        if rows.empty:
            raise ConfigError("run_id", f"no run {run_id!r} in {self.out / 'summary.parquet'}",
                              "give one of .summary['run_id']")
        rel = rows.iloc[0]
        if isinstance(rel, str) and rel:
            return read_log(self.out / rel)
        from wmr.apps.batch.rerun import open_batch, rerun_run

        if not rerun:
            policy = open_batch(self.out, "out").log
            raise ConfigError("run_id", f"the batch's log policy ({policy.describe()}) kept no "
                              f"log of run {run_id}",
                              f"make it again with its full log: .log({run_id!r}, rerun=True), "
                              f"or wmr rerun {self.out} {run_id}")
        return read_log(rerun_run(self.out, run_id)["mcap"])

    def _repr_html_(self) -> str:
        counts = self.summary["status"].value_counts().to_dict()
        head = ", ".join(f"{n} {s}" for s, n in counts.items())
        return f"<b>{html.escape(str(self.out))}</b>: {head}" + str(
            self.summary.to_html(max_rows=20))


def batch(spec: str | Path, out: str | Path | None = None, *,
          workers: int | None = None, scheduler: str | None = None,
          run_timeout_s: float | None = None, max_runs: int | None = None, fmi: int = 3,
          fmu: str | Path | None = None, fmu_map: str | Path | None = None,
          log: str | None = None, log_every: int | None = None,
          progress: bool = False) -> BatchResult:
    """Many runs, as ``wmr batch`` makes them (resumable: done runs are kept); returns the
    summary as a DataFrame (``docs/batch.md``).

    The keywords are the options of ``wmr batch``: ``max_runs`` (``--max-runs``: refuse a
    larger spec), ``run_timeout_s`` (``--run-timeout``; None: 600 s, 0: no limit),
    ``fmu_map`` (``--map``), ``log`` and ``log_every`` (``--log``, ``--log-every``, over the
    spec's ``[log]``), ``progress`` (a bar on stderr; default off in the API).  Both check
    their inputs in :func:`wmr.apps.batch.command.batch_command`: the same one-line errors,
    naming the keyword here.
    """
    _not_in_a_worker_import("batch")
    import pyarrow.parquet as pq

    from wmr.apps.batch.command import BatchRequest, batch_command

    folder, _ = batch_command(BatchRequest(
        spec, out, workers=workers, scheduler=scheduler, run_timeout_s=run_timeout_s,
        max_runs=max_runs, fmi=fmi, fmu=fmu, fmu_map=fmu_map, log=log, log_every=log_every),
        progress=progress)
    return BatchResult(folder, pq.read_table(folder / "summary.parquet").to_pandas())


def replay(logs: str | Path | Sequence[str | Path] = (), *, rrd: str | Path | None = None,
           blueprint: str | Path | None = None, blueprint_for: bool = False,
           viewer: bool | None = None, worst: int | None = None,
           by: str = "time_to_goal_s", status: str | None = None,
           read_limit_mib: float | None = None,
           notebook: bool = False,
           pose_topic: str | None = None) -> ReplayResult | Path | list[Path]:
    """Replay run logs in Rerun, as ``wmr replay`` does: ``logs`` (a file or folder, or a list
    of them) in one recording, shown in a viewer or written to ``rrd``.

    The keywords are the options of ``wmr replay``: ``rrd`` (``--rrd``), ``blueprint``
    (``--blueprint``: write a blueprint for Rerun's own MCAP loader, looking down on
    ``logs`` if given, and replay nothing; returns its path), ``blueprint_for``
    (``--blueprint-for``: ``X.rbl`` beside each log ``X.mcap``, for ``rerun X.mcap X.rbl``;
    returns their paths), ``viewer`` (``--no-viewer`` is
    ``viewer=False``; None: a viewer when there is a screen and no ``rrd``), ``worst``, ``by``
    and ``status`` (``--worst N --by COLUMN``, ``--status failed|timeout``: runs of one batch
    folder, those whose logs were not kept made again into ``DIR/rerun/``, a warning saying
    so), ``read_limit_mib`` (``--read-limit``: the memory a log's read may take, MiB; default
    ``WMR_READ_LIMIT_MIB``, else 1536), ``pose_topic`` (``--pose-topic``: the topic of a
    real robot's poses in a log that is not ours, when it has several; such a log replayed
    with one of ours is aligned to it at the start of motion, the distance between the two
    paths plotted: ``.aligned`` of the result says how).  Both build the same
    :class:`wmr.apps.replay.ReplayRequest`, checked in :func:`wmr.apps.replay.replay_logs`:
    the same one-line errors.

    ``notebook=True`` (no option of the command: a notebook's own) shows the same recording
    and blueprint inline, in the cell's output, through rerun-notebook (``pip install
    'wmr-cosim[notebook]'``; without it, or outside a notebook, one ConfigError saying so);
    no viewer is spawned and no ``.rrd`` written (``rrd`` and ``viewer=True`` are refused
    with it), and ``.viewer`` of the result is that viewer (``rerun.notebook.Viewer``).

    Returns
    -------
    ReplayResult, Path or list of Path
        ``.runs``, ``.steps``, ``.rrd`` (None when only a viewer got it), ``.spawned``,
        ``.warnings``, ``.viewer`` (``notebook=True``); or the blueprint(s) written.
    """
    from wmr.apps.replay import ReplayRequest, replay_logs

    inputs = [logs] if isinstance(logs, str | Path) else list(logs)
    def say(line: str) -> None:
        import warnings

        warnings.warn(line, stacklevel=3)

    from wmr.adapters.mcap.reader import read_limit

    with read_limit(read_limit_mib):
        return replay_logs(ReplayRequest(inputs, rrd=rrd, blueprint=blueprint,
                                         blueprint_for=blueprint_for, viewer=viewer,
                                         worst=worst, by=by, status=status, notebook=notebook,
                                         pose_topic=pose_topic), say=say)


__all__ = ["BatchResult", "Log", "RunResult", "batch", "load_scenario", "optimal",
           "read_log", "replay", "run"]

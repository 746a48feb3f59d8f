"""What ``wmr replay`` and :func:`wmr.replay` both do: check the inputs, then replay run logs in
Rerun (:func:`wmr.adapters.rerun.replay.replay`) or write blueprints for Rerun's own MCAP
loader (:func:`wmr.adapters.rerun.blueprint.write_blueprint`, one file;
:func:`~wmr.adapters.rerun.blueprint.write_log_blueprint`, ``X.rbl`` beside each ``X.mcap``)."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from wmr.infra.errors import ConfigError

if TYPE_CHECKING:
    from wmr.adapters.rerun.replay import ReplayResult

@dataclass(frozen=True)
class ReplayRequest:
    """A replay, as ``wmr replay`` and :func:`wmr.replay` ask for it (their options and
    keywords, ``docs/replay.md``); errors name its fields.

    Attributes
    ----------
    logs
        ``.mcap`` run logs and folders searched recursively for them.
    rrd
        Write the recording to this ``.rrd`` file.
    blueprint
        Write a Rerun blueprint (``.rbl``) for a log opened with Rerun's own MCAP loader
        (``docs/replay.md``), and stop.
    blueprint_for
        Write ``X.rbl`` beside each log ``X.mcap`` (looking down on its own run), so that
        ``rerun X.mcap X.rbl`` applies it, and stop.
    viewer
        Open a viewer: None when there is a screen and no ``rrd``, False never (then the
        recording goes to ``rrd`` or next to the input).
    worst, by, status
        With one batch folder in ``logs``: replay its ``worst`` runs by the summary column
        ``by`` (the failed and timed-out runs first), or every run of ``status``
        (``failed``, ``timeout``); a run whose log the batch did not keep is made again with
        a full log into ``DIR/rerun/`` (:func:`wmr.apps.batch.rerun.batch_logs`).  When the
        batch's spec has ``optimal``, each chosen run's minimum-time path is solved again and
        drawn beside it, labelled ``optimal``.
    notebook
        Show the recording in the notebook's inline viewer (rerun-notebook) instead of a
        viewer or an ``.rrd``; refused before any run is read or made again where it cannot
        be shown (:func:`wmr.adapters.rerun.replay.check_notebook`).
    pose_topic
        The topic of a real robot's poses in a log that is not ours, when it holds several
        (:func:`wmr.adapters.mcap.read_run`); such a log replayed with one of ours is
        aligned to it at the start of motion (:mod:`wmr.adapters.rerun.overlay`).
    """

    logs: Sequence[str | os.PathLike[str]] = ()
    rrd: str | os.PathLike[str] | None = None
    blueprint: str | os.PathLike[str] | None = None
    blueprint_for: bool = False
    viewer: bool | None = None
    worst: int | None = None
    by: str = "time_to_goal_s"
    status: str | None = None
    notebook: bool = False
    pose_topic: str | None = None


def replay_logs(request: ReplayRequest, say: Callable[[str], None] | None = None
                ) -> ReplayResult | Path | list[Path]:
    """Replay the request's logs (files and folders of them) in one Rerun recording, or, with
    ``blueprint``, write that blueprint file (looking straight down on the logs, if given)
    and replay nothing.

    Parameters
    ----------
    request
        What to replay and how (:class:`ReplayRequest`).
    say
        Told of each run of a batch made again because the batch kept no log of it, and of a
        chosen run whose optimum is not solved.

    Returns
    -------
    ReplayResult, Path or list of Path
        What the replay did, the blueprint written, or those written beside the logs.

    Raises
    ------
    ConfigError
        No log given, or an output that cannot be written (named by the request's fields).
    LogError
        A log that cannot be read.
    """
    logs, rrd, blueprint, viewer = request.logs, request.rrd, request.blueprint, request.viewer
    worst, status, notebook = request.worst, request.status, request.notebook
    from wmr.infra.outputs import check_output

    if request.blueprint_for:
        from wmr.adapters.rerun.blueprint import log_blueprint_path, write_log_blueprint
        from wmr.adapters.rerun.replay import find_logs, raw_view

        if not logs:
            raise ConfigError("blueprint_for", "no log given",
                              "give run logs or folders of them")
        found = find_logs(logs)
        for log in found:  # every output checked before the first is written
            check_output(log_blueprint_path(log.path), "blueprint_for", suffix=".rbl")
        written = []
        for log in found:
            own = raw_view([log.path])  # each looks down on its own run, plots its range
            written.append(write_log_blueprint(log.path, own.frame, sensing=own.sensing,
                                               y_ranges=own.y_ranges))
        return written
    if blueprint is not None:
        from wmr.adapters.rerun.blueprint import write_blueprint

        view = None
        if logs:  # look straight down on these runs (and plot their covariance, their ranges)
            from wmr.adapters.rerun.replay import raw_view

            view = raw_view(logs)
        out = check_output(blueprint, "blueprint", suffix=".rbl")
        out.parent.mkdir(parents=True, exist_ok=True)  # as rrd does
        return write_blueprint(out, frame=view.frame if view else None,
                               sensing=view.sensing if view else False,
                               y_ranges=view.y_ranges if view else None)
    if not logs:
        raise ConfigError("logs", "no log given", "give run logs or folders of them")
    if notebook:  # before --worst makes runs again, only to find no viewer to show them in
        from wmr.adapters.rerun.replay import check_notebook

        check_notebook(rrd, viewer)
    optimal_paths: dict[Path, NDArray[np.float64]] = {}
    if worst is not None or status is not None:
        chosen = _chosen_runs(logs, worst, request.by, status, say)
        optimal_paths = _optimal_paths(Path(logs[0]), chosen, say)
        logs = [log for _, log in chosen]
    else:
        _kept_logs(logs)
    if rrd is not None:
        check_output(rrd, "rrd", suffix=".rrd")
    from wmr.adapters.rerun.replay import replay

    return replay(logs, rrd=rrd, spawn=viewer, notebook=notebook, optimal_paths=optimal_paths,
                  pose_topic=request.pose_topic)


def _optimal_paths(out: Path, chosen: Sequence[tuple[str, Path]],
                   say: Callable[[str], None] | None) -> dict[Path, NDArray[np.float64]]:
    """The minimum-time path (x, y, m; shape ``(n, 2)``) of each ``chosen`` run (run id, log)
    of the batch ``out``, by log, when its spec has ``optimal``; else none.

    The batch keeps the optimum's numbers, not its path: the OCP is solved again for these few
    runs, as the batch's worker solved it (:func:`wmr.apps.optimal.optimum_fields`: the run's
    start, goal, robot and limits, minimum time).  A run whose OCP is not solved gets no path,
    and ``say`` is told why.
    """
    from wmr.apps.batch.rerun import open_batch

    folder = open_batch(out)
    if folder.spec.optimal is None:
        return {}
    from wmr.adapters.ocp import OptimalLimits, OptimalProblem, solve_optimal

    paths: dict[Path, NDArray[np.float64]] = {}
    for run_id, log in chosen:
        spec = folder.run(run_id).spec
        res = solve_optimal(OptimalProblem(spec.start, spec.goal, spec.params,
                                           limits=OptimalLimits.like(spec.limits)))
        if res.status == "solved":
            paths[log] = np.column_stack([res.states["x"], res.states["y"]])
        elif say is not None:
            say(f"run {run_id}: no optimal path ({res.status}: {res.message})")
    return paths


def _chosen_runs(logs: Sequence[str | os.PathLike[str]], worst: int | None, by: str,
                 status: str | None,
                 say: Callable[[str], None] | None) -> list[tuple[str, Path]]:
    """The runs ``--worst``/``--status`` choose in the one batch folder of ``logs``: (run id,
    log), the log made again where the batch kept none."""
    from wmr.apps.batch.rerun import batch_logs, pick_runs

    option = "worst" if worst is not None else "status"
    if worst is not None and status is not None:
        raise ConfigError(option, "given with status=STATUS", "give one of them")
    if len(logs) != 1 or not Path(logs[0]).is_dir():
        raise ConfigError(option, "chooses runs of one batch folder",
                          "give one batch folder (the --out of wmr batch)")
    out = Path(logs[0])
    picked = pick_runs(out, worst=worst, by=by, status=status)
    return list(zip([run_id for run_id, _ in picked], batch_logs(out, picked, say),
                    strict=True))


def _kept_logs(logs: Sequence[str | os.PathLike[str]]) -> None:
    """A batch folder given whole that holds no log: say its log policy and how to see its
    runs, not only that the folder has no ``.mcap`` file."""
    from wmr.apps.batch.rerun import BATCH_JSON, open_batch

    for item in logs:
        folder = Path(item)
        if not (folder / BATCH_JSON).is_file() or any(folder.rglob("*.mcap")):
            continue
        policy = open_batch(folder, "logs").log
        raise ConfigError("logs", f"{folder} is a batch whose log policy "
                          f"({policy.describe()}) kept no log",
                          "make runs again with their full logs: worst=N [by=COLUMN], or "
                          f"status=failed|timeout, or wmr rerun {folder} RUN_ID")


__all__ = ["ReplayRequest", "replay_logs"]

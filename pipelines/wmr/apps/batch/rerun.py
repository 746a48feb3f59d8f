"""``wmr rerun``: one run of a batch made again, bit for bit, with its full log, from the batch
folder alone.

The batch folder keeps what a run needs: the copy of its spec (``spec-<file>``, the file every
run's log attaches), ``batch.json`` (the spec's path, which names its runs and resolves its
relative paths, and the SHA-256 of the FMU that ran them) and the summary.  A run is made from
its index as the batch made it (:attr:`wmr.apps.batch.spec.BatchSpec.runs`) and run by the
worker's own code (:class:`wmr.apps.batch.worker.PlantHolder`), with a full log, into
``DIR/rerun/<run_id>.mcap`` by default: a folder of its own, never mixed with the logs the
batch kept under ``DIR/runs``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from wmr.apps.batch.runner import DEFAULT_RUN_TIMEOUT_S
from wmr.apps.batch.spec import BatchRun, BatchSpec, parse_batch, run_index
from wmr.apps.batch.worker import DISK_FULL, PlantHolder, Task, fmu_digest
from wmr.apps.run import FULL_LOGS, LogPolicy
from wmr.infra.errors import ConfigError, DiskFullError

#: The folder of a batch that holds its reruns' logs (``DIR/rerun/<run_id>.mcap``).
RERUN_DIR: Final = "rerun"
#: The file of a batch folder that names its spec, FMU and log policy (written by the runner).
BATCH_JSON: Final = "batch.json"


def rerun_log_path(out_dir: Path, run_id: str) -> Path:
    """Where :func:`rerun_run` writes the log of ``run_id`` by default."""
    return out_dir / RERUN_DIR / f"{run_id}.mcap"


@dataclass(frozen=True)
class BatchFolder:
    """What a batch folder says of its batch (``batch.json`` and the spec's copy).

    Attributes
    ----------
    out_dir
        The folder.
    spec
        The spec, expanded again from its copy under its original path.
    attachment
        The spec's copy, which every run's log attaches.
    fmu_name, fmu_sha256
        The FMU file's name and :func:`~wmr.apps.batch.worker.fmu_digest` of the batch.
    log
        The log policy of the batch's last invocation.
    """

    out_dir: Path
    spec: BatchSpec
    attachment: Path
    fmu_name: str
    fmu_sha256: str
    log: LogPolicy

    def run(self, run_id: str, field: str = "RUN_ID") -> BatchRun:
        """The spec's run ``run_id``; a :class:`ConfigError` naming ``field`` when the batch
        has no such run."""
        index = run_index(run_id)
        runs = self.spec.runs
        if index is None or not 0 <= index < len(runs):
            raise ConfigError(field, f"{run_id!r} is not a run of {self.out_dir} "
                              f"({len(runs)} runs)",
                              "give a run id of its summary (summary.parquet), e.g. "
                              f"{runs[0].run_id if runs else '0000-0123abcd'}")
        run = runs[index]
        if run.run_id != run_id:
            raise ConfigError(field, f"run {index} of {self.out_dir} is {run.run_id}, not "
                              f"{run_id} (another spec's run)",
                              "give a run id of its summary (summary.parquet)")
        return run


def open_batch(out_dir: str | os.PathLike[str], field: str = "DIR") -> BatchFolder:
    """Read a batch folder's ``batch.json`` and expand its spec's copy again.

    Raises
    ------
    ConfigError
        Not a batch folder (no ``batch.json``), or its spec's copy is missing.
    """
    from wmr.config.scenario import read_toml

    out = Path(out_dir)
    try:
        info = json.loads((out / BATCH_JSON).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(field, f"{out} is not a batch folder (no {BATCH_JSON})",
                          "give the --out folder of a wmr batch") from None
    except (OSError, ValueError) as exc:
        raise ConfigError(field, f"cannot read {out / BATCH_JSON}: {exc}",
                          "run the same wmr batch command again to rewrite it") from None
    if not isinstance(info, dict) or not isinstance(info.get("spec"), str) \
            or not isinstance(info.get("fmu_sha256"), str):
        raise ConfigError(field, f"{out / BATCH_JSON} has no spec or fmu_sha256",
                          "run the same wmr batch command again to rewrite it")
    spec_path = Path(info["spec"])
    copy = out / f"spec-{spec_path.name}"
    if not copy.is_file():
        raise ConfigError(field, f"{out} holds no copy of its spec ({copy.name})",
                          "rerun the batch from its spec file with wmr batch")
    data, raw = read_toml(copy, "spec")
    # parsed under its original path: that names the runs and resolves the relative paths
    # (fmu, controller_fmu) as the batch did, so every run is the batch's, digest and all
    spec = parse_batch(data, source=str(spec_path), path=spec_path, raw=raw)
    policy = info.get("log")
    log = LogPolicy(**policy) if isinstance(policy, dict) else FULL_LOGS
    return BatchFolder(out, spec, copy, str(info.get("fmu", "")), info["fmu_sha256"], log)


def _batch_fmu(folder: BatchFolder, fmu: str | os.PathLike[str] | None,
               fmu_map: str | os.PathLike[str] | None, field: str) -> tuple[Path, Any]:
    """The FMU (and variable map) that ran the batch: ``fmu`` if given, else the spec's, else
    the project's own build of the same name; its digest must be the batch's."""
    from wmr.adapters.fmi.varmap import load_map
    from wmr.apps.run import default_fmu
    from wmr.infra import paths

    spec = folder.spec
    map_path = Path(fmu_map) if fmu_map is not None else spec.fmu_map
    var_map = load_map(map_path) if map_path is not None else None
    if fmu is not None or spec.fmu is not None:
        path = Path(fmu) if fmu is not None else spec.fmu
        assert path is not None
        if not path.is_file():
            raise ConfigError(field, f"no such file: {path}", "give the batch's FMU file")
        candidates = [path]
    else:
        # the project's build: for every platform (wmr fmu build) if there, else the host's
        # (wmr run and wmr batch build it); the one the batch ran has its name and digest
        everywhere = paths.default_fmu_dir() / folder.fmu_name
        if folder.fmu_name and everywhere.is_file() \
                and fmu_digest(everywhere, var_map) == folder.fmu_sha256:
            return everywhere, var_map
        candidates = [p for p in (default_fmu(3), default_fmu(2))
                      if p.name == folder.fmu_name][:1]
    for path in candidates:
        if fmu_digest(path, var_map) == folder.fmu_sha256:
            return path, var_map
    given = f"{candidates[-1]} is another" if candidates else "the project's build is another"
    raise ConfigError(field, f"the batch ran {folder.fmu_name or 'an FMU'} (sha256 "
                      f"{folder.fmu_sha256[:12]}); {given} FMU",
                      "give the batch's own FMU (and map) with fmu=FILE.fmu [fmu_map="
                      "MAP.toml]: a run is only reproduced on the FMU that ran it")


def rerun_run(out_dir: str | os.PathLike[str], run_id: str, *,
              out: str | os.PathLike[str] | None = None,
              fmu: str | os.PathLike[str] | None = None,
              fmu_map: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """Make run ``run_id`` of the batch in ``out_dir`` again, with a full log.

    Parameters
    ----------
    out_dir
        The batch folder (the ``--out`` of ``wmr batch``).
    run_id
        The run's id (``NNNN-hhhhhhhh``, the summary's ``run_id``).
    out
        The log (default :func:`rerun_log_path`: ``DIR/rerun/<run_id>.mcap``).
    fmu, fmu_map
        The FMU that ran the batch, when it was neither the spec's nor the project's build
        (``wmr batch --fmu``), and its variable map if the spec names none (``--map``);
        checked against the batch's digest.

    Returns
    -------
    dict
        The run's result record (:func:`wmr.apps.run.run_to_log`), whose result fields equal
        the run's summary row; ``mcap`` is the new log.

    Raises
    ------
    ConfigError
        Not a batch folder, no such run, not the batch's FMU, or an output that cannot be
        written (named by the keywords: ``out_dir``, ``run_id``, ``fmu``, ``out``).
    DiskFullError
        The log could not be written for lack of space.
    """
    from wmr.infra.outputs import check_output

    folder = open_batch(out_dir, "out_dir")
    run = folder.run(run_id, "run_id")
    path = check_output(out if out is not None else rerun_log_path(folder.out_dir, run_id),
                        "out", suffix=".mcap")
    fmu_path, var_map = _batch_fmu(folder, fmu, fmu_map, "fmu")
    path.parent.mkdir(parents=True, exist_ok=True)
    # the task the batch sent its worker, but with a full log: the same run, kept whole
    task = Task(run.run_id, run.spec, DEFAULT_RUN_TIMEOUT_S, log=FULL_LOGS)
    holder = PlantHolder(fmu_path, var_map)
    try:
        record = holder.run(task, path, folder.attachment)
    finally:
        holder.close()
    if record.pop(DISK_FULL, False):
        raise DiskFullError(str(record.get("message")))
    return record




def pick_runs(out_dir: Path, *, worst: int | None = None, by: str = "time_to_goal_s",
              status: str | None = None) -> list[tuple[str, str | None]]:
    """The runs of a batch that ``wmr replay DIR --worst N [--by COLUMN]`` or ``--status S``
    shows, worst first: ``(run_id, log relative to DIR or None when none was kept)``.

    ``worst``: the ``worst`` runs, the failed and timed-out ones first (the runs without a
    value of ``by`` first among them), then the largest ``by``; ties (timeouts have no time to
    goal) by the largest final position error, then by run id.
    ``status``: every run of that status, in run-id order.
    """
    import math

    import pyarrow.parquet as pq

    from wmr.apps.batch.summary import SUMMARY_PARQUET

    path = out_dir / SUMMARY_PARQUET
    if not path.is_file():
        raise ConfigError("logs",
                          f"{out_dir} is not a batch folder (no {SUMMARY_PARQUET})",
                          "give the --out folder of a wmr batch")
    schema = pq.read_schema(path)
    if status is not None:
        if status not in ("failed", "timeout"):
            raise ConfigError("status", f"unknown status {status!r}",
                              "give failed or timeout")
        table = pq.read_table(path, columns=["run_id", "status", "mcap"],
                              filters=[("status", "=", status)])
        chosen = [(r["run_id"], r["mcap"]) for r in table.to_pylist()]
        if not chosen:
            raise ConfigError("status", f"no {status} run in {out_dir}",
                              "see its summary.parquet for the runs' statuses")
        return chosen
    if worst is None or worst < 1:
        raise ConfigError("worst", f"must be >= 1, got {worst}",
                          "give the number of runs to show, e.g. 5")
    numeric = [f.name for f in schema if f.type in ("double", "int64")]
    if by not in numeric:
        raise ConfigError("by", f"{by!r} is not a numeric column of "
                          f"{path.name}", f"give one of: {', '.join(numeric)}")
    error = "final_position_error_m"
    columns = ["run_id", "status", "mcap", by] + ([error] if error in numeric and error != by
                                                  else [])
    rows = pq.read_table(path, columns=columns).to_pylist()

    def descending(value: float | None) -> float:
        return math.inf if value is None or not math.isfinite(value) else -value

    def rank(row: dict[str, Any]) -> tuple[bool, float, float, str]:
        # without the tie-break, a batch of many timeouts showed its first timeouts by run id
        return (row["status"] == "converged", descending(row[by]),
                descending(row.get(error)), row["run_id"])

    rows.sort(key=rank)
    return [(r["run_id"], r["mcap"]) for r in rows[:worst]]


def batch_logs(out_dir: Path, chosen: list[tuple[str, str | None]],
               say: Callable[[str], None] | None = None) -> list[Path]:
    """The logs of the ``chosen`` runs (:func:`pick_runs`): each the batch kept where it is,
    each it did not made again with a full log into ``DIR/rerun/`` (:func:`rerun_run`),
    ``say`` told of each so made."""
    folder: BatchFolder | None = None
    logs = []
    for run_id, rel in chosen:
        if rel:
            logs.append(out_dir / rel)
            continue
        if folder is None:
            folder = open_batch(out_dir)
        record = rerun_run(out_dir, run_id)
        if say is not None:
            say(f"run {run_id}: its log was not kept ({folder.log.describe()}): made again "
                f"with a full log into {record['mcap']}")
        logs.append(Path(record["mcap"]))
    return logs


__all__ = ["BATCH_JSON", "RERUN_DIR", "BatchFolder", "batch_logs", "open_batch", "pick_runs",
           "rerun_log_path", "rerun_run"]

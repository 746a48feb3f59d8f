"""``wmr batch`` (many runs, locally or on Dask) and ``wmr report`` (a batch's summary as a
report)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from wmr.cli.run import add_fmu_choice, add_log_choice
from wmr.cli.shared import errors_as_options
from wmr.infra.errors import ConfigError

if TYPE_CHECKING:
    from wmr.apps.batch import BatchSpec


#: ``wmr batch``'s options by the keyword of :func:`wmr.batch` (and of its errors) they give.
BATCH_OPTIONS: dict[str, str] = {
    "out": "--out", "workers": "--workers", "scheduler": "--scheduler",
    "run_timeout_s": "--run-timeout", "max_runs": "--max-runs", "fmi": "--fmi", "fmu": "--fmu",
    "fmu_map": "--map", "log": "--log", "log_every": "--log-every",
}


def _cmd_batch(args: argparse.Namespace) -> int:
    from wmr.apps.batch.command import BatchRequest, batch_command, load_checked
    from wmr.config.naming import plural

    def warn(field: str, message: str) -> None:
        print(f"wmr: warning: {BATCH_OPTIONS.get(field, field)} {message}", file=sys.stderr)

    with errors_as_options(BATCH_OPTIONS):
        if args.check:
            batch, _, _ = load_checked(args.spec, workers=args.workers,
                                       scheduler=args.scheduler,
                                       run_timeout_s=args.run_timeout, max_runs=args.max_runs,
                                       warn=warn)
            return _check_runs(batch, args.progress)
        out, result = batch_command(BatchRequest(
            args.spec, args.out, workers=args.workers, scheduler=args.scheduler,
            run_timeout_s=args.run_timeout, max_runs=args.max_runs, fmi=args.fmi, fmu=args.fmu,
            fmu_map=args.map or None, log=args.log, log_every=args.log_every),
            progress=args.progress, warn=warn)
    c = result.counts
    rate = len(result.executed) / result.wall_s * 60.0 if result.wall_s > 0 else 0.0
    state = "interrupted" if result.interrupted else "done"
    print(f"{state}: {result.finished}/{plural(result.total, 'run')} in the summary "
          f"({c.get('converged', 0)} converged, {c.get('timeout', 0)} timeout, "
          f"{c.get('failed', 0)} failed); {len(result.executed)} run now, "
          f"{result.skipped} done before; {result.wall_s:.1f} s ({rate:.0f} runs/min); "
          f"{result.log.describe()}: {plural(result.logs_kept, 'log')} kept now",
          file=sys.stderr)
    print(out / "summary.parquet")
    if result.interrupted:
        print("wmr: interrupted; rerun the same command to finish the batch", file=sys.stderr)
        return 130
    return 0


def _check_runs(batch: BatchSpec, progress: bool | None) -> int:
    """``wmr batch --check``: make every run of ``batch`` (a :class:`ConfigError` names the
    first invalid one) and say how many there are; nothing is run or written."""
    from tqdm import tqdm

    from wmr.config.naming import plural

    n = 0
    for _ in tqdm(batch.runs, desc=f"checking {batch.name}", unit="run", file=sys.stderr,
                  disable=None if progress is None else not progress, dynamic_ncols=True):
        n += 1
    print(f"{batch.name}: {plural(n, 'run')}, all valid", file=sys.stderr)
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from wmr.apps.batch.report import write_report
    from wmr.infra.outputs import check_output

    if args.max_plots < 0:
        raise ConfigError("--max-plots", f"must be >= 0, got {args.max_plots}",
                          "give e.g. --max-plots 8, or 0 for no input plots")
    if args.json:
        import json

        from wmr.apps.batch.report_data import report_data

        print(json.dumps(report_data(Path(args.dir), worst=args.worst), allow_nan=False))
        return 0
    check_output(Path(args.dir) / "report", "DIR", "dir")
    print(write_report(Path(args.dir), max_plots=args.max_plots, worst=args.worst,
                       progress=lambda line: print(f"wmr: {line}", file=sys.stderr, flush=True)))
    return 0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``batch`` and ``report`` to the ``wmr`` sub-commands."""
    p = sub.add_parser(
        "batch", help="many runs (sweeps, Monte Carlo) on all cores or a Dask cluster",
        description="Run every run of a batch spec (a scenario file plus [grid], [[list]] and "
                    "[random] sections; see docs/batch.md) and write OUT/summary.parquet (and "
                    "OUT/summary.csv up to 1000 runs), one row per run, and the logs the log "
                    "policy keeps under OUT/runs (in shards of 1000 runs over 1000 runs).  "
                    "Rerunning the same command skips the runs already done.  Exit status 0 when "
                    "the batch completed (whatever the runs' statuses), 130 when interrupted (143"
                    " on SIGTERM), 1 on bad input, a full disk, when the first runs all fail "
                    "before their first step (a broken FMU), or when the Dask scheduler goes away"
                    " or has no workers (the runs finished are kept: rerun the same command).")
    p.add_argument("spec", metavar="SPEC", help="batch spec or scenario (.toml or name)")
    p.add_argument("--out", metavar="DIR", help="batch folder (default batches/SPEC_NAME)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="local worker processes (default: one per core)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on this Dask scheduler (e.g. tcp://127.0.0.1:8786)")
    p.add_argument("--run-timeout", type=float, default=600.0, metavar="S",
                   help="wall-clock limit of one run, s (default 600; 0: none); a run past it "
                        "is recorded as 'timeout' and the batch goes on")
    p.add_argument("--max-runs", type=int, metavar="N",
                   help="refuse a spec of more runs than this (default one million; counted "
                        "before anything is expanded)")
    add_fmu_choice(p)
    add_log_choice(p, "the spec's [log], else full up to 1000 runs and failed over")
    p.add_argument("--check", action="store_true",
                   help="make every run of the spec and stop: the first invalid one is named "
                        "(loading checks every grid value and list entry at once, and every "
                        "run of a spec of up to 1000; a larger spec's other runs are checked "
                        "as the batch reaches them)")
    bar = p.add_mutually_exclusive_group()
    bar.add_argument("--progress", dest="progress", action="store_true", default=None,
                     help="show the progress bar even when stderr is not a terminal")
    bar.add_argument("--no-progress", dest="progress", action="store_false",
                     help="no progress bar")
    p.set_defaults(handler=_cmd_batch)

    r = sub.add_parser(
        "report", help="a batch's summary as a Markdown report with plots",
        description="Write DIR/report/report.md and PNG plots from DIR/summary.parquet and "
                    "print the report's path: the success rate with its 95 % Wilson interval "
                    "(per status, per controller), every varied input ranked by its influence "
                    "on convergence, time to goal and energy (main effects for a grid, "
                    "RBD-FAST otherwise), the worst runs and every failed or timed-out run with "
                    "its inputs and the command that reruns it, the spread of the metrics, a "
                    "map of a 2-D grid, the region of attraction when the start varies, and "
                    "plots against each varied input.  With --json, print the same numbers as "
                    "one JSON object instead and write nothing (docs/batch.md, \"Report\").")
    r.add_argument("dir", metavar="DIR", help="a batch folder (the --out of wmr batch)")
    r.add_argument("--max-plots", type=int, default=8, metavar="N",
                   help="plot at most N varied inputs (default 8; the spec's own fields "
                        "first)")
    r.add_argument("--worst", type=int, default=10, metavar="N",
                   help="list the N worst runs by time to goal, final position error and "
                        "energy (default 10)")
    r.add_argument("--json", action="store_true",
                   help="print every table's numbers as one JSON object on stdout and write "
                        "nothing")
    r.set_defaults(handler=_cmd_report)

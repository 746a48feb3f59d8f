"""``wmr batch`` (many runs, locally or on Dask) and ``wmr report`` (a batch's summary as a
report)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from wmr.errors import ConfigError


def _default_out(spec: str) -> Path:
    return Path("batches") / Path(spec).stem


def _cmd_batch(args: argparse.Namespace) -> int:
    from wmr.batch import load_batch, run_batch
    from wmr.fmu.varmap import load_map

    batch = load_batch(args.spec)
    out = Path(args.out) if args.out else _default_out(args.spec)
    if args.scheduler is not None and args.workers is not None:
        raise ConfigError("--workers", "has no effect with --scheduler",
                          "size the Dask cluster instead")
    progress = None if args.progress is None else args.progress
    result = run_batch(batch, out, workers=args.workers, scheduler=args.scheduler,
                       run_timeout_s=args.run_timeout if args.run_timeout > 0 else None,
                       fmu_path=args.fmu, fmi_version=args.fmi, progress=progress,
                       var_map=load_map(args.map) if args.map else None)
    c = result.counts
    rate = len(result.executed) / result.wall_s * 60.0 if result.wall_s > 0 else 0.0
    state = "interrupted" if result.interrupted else "done"
    print(f"{state}: {result.finished}/{result.total} runs in the summary "
          f"({c.get('converged', 0)} converged, {c.get('timeout', 0)} timeout, "
          f"{c.get('failed', 0)} failed); {len(result.executed)} run now, "
          f"{result.skipped} done before; {result.wall_s:.1f} s ({rate:.0f} runs/min)",
          file=sys.stderr)
    print(out / "summary.parquet")
    if result.interrupted:
        print("wmr: interrupted; rerun the same command to finish the batch", file=sys.stderr)
        return 130
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from wmr.batch.report import write_report

    print(write_report(Path(args.dir), max_plots=args.max_plots))
    return 0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``batch`` and ``report`` to the ``wmr`` sub-commands."""
    p = sub.add_parser(
        "batch", help="many runs (sweeps, Monte Carlo) on all cores or a Dask cluster",
        description="Run every run of a batch spec (a scenario file plus [grid], [[list]] and "
                    "[random] sections; see docs/batch.md) and write OUT/summary.parquet and "
                    "OUT/summary.csv, one row per run, and OUT/runs/<id>.mcap.  Rerunning the "
                    "same command skips the runs already done.  Exit status 0 when the batch "
                    "completed (whatever the runs' statuses), 130 when interrupted, 1 on bad "
                    "input.")
    p.add_argument("spec", metavar="SPEC", help="batch spec or scenario (.toml or name)")
    p.add_argument("--out", metavar="DIR", help="batch folder (default batches/SPEC_NAME)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="local worker processes (default: one per core)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on this Dask scheduler (e.g. tcp://127.0.0.1:8786)")
    p.add_argument("--run-timeout", type=float, default=600.0, metavar="S",
                   help="wall-clock limit of one run, s (default 600; 0: none); a run past it "
                        "is recorded as 'timeout' and the batch goes on")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=3,
                   help="FMI version of the FMU to drive (default 3)")
    p.add_argument("--fmu", metavar="FILE.fmu",
                   help="drive this FMU instead of the project's own build")
    p.add_argument("--map", metavar="FILE.toml",
                   help="variable map of an FMU made by another tool (docs/fmu_map.md)")
    bar = p.add_mutually_exclusive_group()
    bar.add_argument("--progress", dest="progress", action="store_true", default=None,
                     help="show the progress bar even when stderr is not a terminal")
    bar.add_argument("--no-progress", dest="progress", action="store_false",
                     help="no progress bar")
    p.set_defaults(handler=_cmd_batch)

    r = sub.add_parser(
        "report", help="a batch's summary as a Markdown report with plots",
        description="Write DIR/report/report.md and PNG plots (success rate, time to goal and "
                    "path length against the varied inputs, histograms of the spread) from "
                    "DIR/summary.parquet; print the report's path.")
    r.add_argument("dir", metavar="DIR", help="a batch folder (the --out of wmr batch)")
    r.add_argument("--max-plots", type=int, default=8, metavar="N",
                   help="plot at most N varied inputs (default 8)")
    r.set_defaults(handler=_cmd_report)

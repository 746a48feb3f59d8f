"""``wmr rerun``: one run of a batch made again, with its full log
(:func:`wmr.apps.batch.rerun.rerun_run`)."""

from __future__ import annotations

import argparse

from wmr.cli.shared import errors_as_options

#: ``wmr rerun``'s arguments and options by the keyword of
#: :func:`wmr.apps.batch.rerun.rerun_run` (and of its errors) they give.
RERUN_OPTIONS: dict[str, str] = {"out_dir": "DIR", "run_id": "RUN_ID", "out": "--out",
                                 "fmu": "--fmu", "fmu_map": "--map"}


def _cmd_rerun(args: argparse.Namespace) -> int:
    from wmr.apps.batch.rerun import rerun_run
    from wmr.cli.run import exit_status, print_result

    with errors_as_options(RERUN_OPTIONS):
        record = rerun_run(args.dir, args.run_id, out=args.out, fmu=args.fmu,
                           fmu_map=args.map)
    print_result(record, args.json, sensors=False)
    return exit_status(record)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``rerun`` sub-command."""
    p = sub.add_parser(
        "rerun", help="one run of a batch made again, bit for bit, with its full log",
        description="Make run RUN_ID of the batch in DIR again from the batch folder alone "
                    "(its spec's copy and batch.json), on the FMU that ran it, with a full "
                    "log, whatever the batch's log policy kept: its result equals the run's "
                    "summary row.  The log goes to DIR/rerun/RUN_ID.mcap unless --out says "
                    "otherwise (never among the batch's own logs in DIR/runs).  Exit status: "
                    "0 converged, 3 timeout, 1 failed or bad input.")
    p.add_argument("dir", metavar="DIR", help="a batch folder (the --out of wmr batch)")
    p.add_argument("run_id", metavar="RUN_ID",
                   help="the run's id, as the summary's run_id column gives it")
    p.add_argument("--out", metavar="LOG.mcap",
                   help="log file (default DIR/rerun/RUN_ID.mcap)")
    p.add_argument("--fmu", metavar="FILE.fmu",
                   help="the FMU that ran the batch, if it was given to wmr batch with --fmu "
                        "(checked against the batch's digest)")
    p.add_argument("--map", metavar="FILE.toml",
                   help="its variable map, if it was given to wmr batch with --map")
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object on the last line")
    p.set_defaults(handler=_cmd_rerun)

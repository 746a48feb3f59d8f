"""``wmr replay`` (run logs in Rerun) and ``wmr figures`` (the paper's figures as PNG files)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from wmr.cli.shared import errors_as_options
from wmr.infra.errors import ConfigError


def _warn(line: str) -> None:
    print(f"wmr: warning: {line}", file=sys.stderr, flush=True)


#: ``wmr replay``'s options by the keyword of :func:`wmr.replay` (and of its errors) they give.
REPLAY_OPTIONS: dict[str, str] = {
    "logs": "FILE.mcap|DIR", "rrd": "--rrd", "blueprint": "--blueprint",
    "blueprint_for": "--blueprint-for", "worst": "--worst", "by": "--by", "status": "--status",
    "pose_topic": "--pose-topic", "read_limit_mib": "--read-limit",
}


def _cmd_replay(args: argparse.Namespace) -> int:
    from wmr.adapters.mcap.reader import read_limit
    from wmr.apps.replay import ReplayRequest, replay_logs

    try:
        with errors_as_options(REPLAY_OPTIONS), read_limit(args.read_limit):
            request = ReplayRequest(args.logs, rrd=args.rrd, blueprint=args.blueprint,
                                    blueprint_for=args.blueprint_for,
                                    viewer=False if args.no_viewer else None,
                                    worst=args.worst, by=args.by, status=args.status,
                                    pose_topic=args.pose_topic)
            result = replay_logs(request, say=lambda line: print(f"wmr: {line}",
                                                                 file=sys.stderr, flush=True))
    except ConfigError as exc:
        if exc.field != "--blueprint-for" or exc.problem != "no log given":
            raise
        raise ConfigError(exc.field, exc.problem,
                          f"{exc.fix}: wmr replay --blueprint-for X.mcap") from None
    if isinstance(result, list):  # --blueprint-for: X.rbl beside each X.mcap
        for path in result:
            print(path)
        print(f"wrote {len(result)} blueprint{'s' if len(result) != 1 else ''}; open a log "
              f"with Rerun's own loader and its blueprint: rerun "
              f"{result[0].with_suffix('.mcap')} {result[0]}", file=sys.stderr)
        return 0
    if isinstance(result, Path):  # --blueprint
        from wmr.adapters.rerun.blueprint import APPLICATION_ID

        print(result)
        print(f"wrote the blueprint; open a log with Rerun's own loader: rerun mcap convert "
              f"RUN.mcap --timeline-type duration --application-id {APPLICATION_ID} -o RUN.rrd"
              f" && rerun RUN.rrd {result}", file=sys.stderr)
        return 0
    for line in result.warnings:
        _warn(line)
    for line in result.skipped:
        print(f"wmr: {line}", file=sys.stderr, flush=True)
    for line in result.aligned:
        print(f"wmr: {line}", file=sys.stderr, flush=True)
    steps = sum(result.steps.values())
    runs = f"{len(result.runs)} run{'s' if len(result.runs) != 1 else ''}, {steps} steps"
    if result.spawned:
        print(f"replayed {runs} in the Rerun viewer", file=sys.stderr)
    if result.rrd is not None:
        print(result.rrd)
        print(f"wrote {runs}; open it with: rerun {result.rrd}", file=sys.stderr)
    return SKIPPED_STATUS if result.skipped else 0


#: Exit status of ``wmr replay`` when the others were replayed but some logs were skipped.
SKIPPED_STATUS = 4


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``replay`` sub-command."""
    from wmr.cli.log import add_read_limit

    p = sub.add_parser(
        "replay", help="replay run logs in Rerun (a viewer, or an .rrd file)",
        description="Replay MCAP run logs in Rerun: the path, pose, goal and the points D and "
                    "R in a 2-D view, and the errors, speeds, torques and PI terms on the "
                    "sim_time timeline.  Several logs (or folders of them) go into one "
                    "recording, each under runs/<name>.  Opens a viewer when there is a "
                    "screen; otherwise, or with --rrd, writes an .rrd file (default: next to "
                    "the input) and prints its path.  A log that cannot be read, or a link in "
                    "a folder to a file outside it, is skipped with one line: exit status 4 "
                    "(0 when every log was replayed, 1 when none could be).")
    p.add_argument("logs", nargs="*", metavar="FILE.mcap|DIR",
                   help="run logs, or folders searched recursively for *.mcap")
    p.add_argument("--rrd", metavar="OUT.rrd", help="write the recording to this file")
    p.add_argument("--blueprint", metavar="OUT.rbl",
                   help="write a Rerun blueprint that plots a log opened with Rerun's own MCAP "
                        "loader (docs/replay.md), and stop; logs given with it are not replayed: "
                        "the blueprint's scene view looks straight down on them")
    p.add_argument("--blueprint-for", action="store_true",
                   help="write X.rbl beside each log X.mcap (named for it, looking down on its "
                        "run), so that Rerun opening the raw log applies it: rerun X.mcap "
                        "X.rbl (docs/replay.md); and stop")
    p.add_argument("--worst", type=int, metavar="N",
                   help="of one batch folder DIR: its N worst runs by --by (the failed and "
                        "timed-out runs first); a run whose log the batch did not keep is made "
                        "again with a full log into DIR/rerun/ (said on stderr)")
    p.add_argument("--by", default="time_to_goal_s", metavar="COLUMN",
                   help="the summary column --worst ranks by, largest worst (default "
                        "time_to_goal_s)")
    p.add_argument("--status", choices=("failed", "timeout"),
                   help="of one batch folder DIR: every run of this status (made again as "
                        "--worst does when its log was not kept)")
    p.add_argument("--pose-topic", metavar="TOPIC",
                   help="the topic of a real robot's poses (foxglove.PoseInFrame or "
                        "FrameTransform) in a log that is not wmr's, when it has several; "
                        "such a log given with a wmr log is aligned to it at the start of "
                        "motion, the distance between the two paths plotted "
                        "(docs/replay.md)")
    p.add_argument("--no-viewer", action="store_true",
                   help="do not open a viewer even if there is a screen (write the .rrd)")
    add_read_limit(p)
    p.set_defaults(handler=_cmd_replay)

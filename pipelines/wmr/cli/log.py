"""``wmr log recover``: make a killed or damaged run log a finished MCAP file again."""

from __future__ import annotations

import argparse
import sys


def add_read_limit(parser: argparse.ArgumentParser) -> None:
    """Add ``--read-limit MIB``: the memory a log's read may take (``WMR_READ_LIMIT_MIB``)."""
    parser.add_argument("--read-limit", type=float, metavar="MIB",
                        help="memory a log's read may take, MiB (default 1536, or the "
                             "environment variable WMR_READ_LIMIT_MIB): a larger log is read "
                             "up to it, with a warning")


#: The option of each keyword of the reads' errors.
READ_LIMIT_OPTIONS: dict[str, str] = {"read_limit_mib": "--read-limit"}


def _cmd_recover(args: argparse.Namespace) -> int:
    from wmr.adapters.mcap.reader import read_limit
    from wmr.adapters.mcap.recover import recover_log
    from wmr.cli.shared import errors_as_options
    from wmr.infra.outputs import check_output

    if args.out is not None:  # a device or FIFO there is refused even with --force
        check_output(args.out, "--out")
    with errors_as_options(READ_LIMIT_OPTIONS), read_limit(args.read_limit):
        rec = recover_log(args.file, args.out, overwrite=args.force, scene=not args.no_scene)
    for line in rec.lost:
        print(f"wmr: lost: {line}", file=sys.stderr)
    print(f"recovered {rec.messages} messages in {rec.chunks} chunks from {rec.source}",
          file=sys.stderr)
    if rec.scene_added:
        print(f"drew the recovered rows: {', '.join(rec.scene_added)}", file=sys.stderr)
    print(rec.output)
    return 0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``log`` (with its action ``recover``) to the ``wmr`` sub-commands."""
    p = sub.add_parser("log", help="repair run logs (recover a killed or damaged log)")
    actions = p.add_subparsers(dest="log_command", metavar="ACTION", required=True)
    r = actions.add_parser(
        "recover", help="rewrite a killed or damaged log as a finished, indexed MCAP file",
        description="Read every intact record of FILE (a log, or the X.mcap.partial a killed "
                    "run leaves) and write them as a finished MCAP file with its summary and "
                    "index, which any MCAP reader opens; a 'recovery' metadata record says "
                    "what was lost.  The scene topics a killed run did not write (what Rerun "
                    "and Foxglove draw) are made from the rows it holds.  Prints the output's "
                    "path.")
    r.add_argument("file", metavar="FILE", help="the log to recover")
    r.add_argument("-o", "--out", metavar="OUT.mcap",
                   help="output file (default: X.recovered.mcap next to FILE)")
    r.add_argument("--force", action="store_true", help="replace OUT if it exists")
    r.add_argument("--no-scene", action="store_true",
                   help="do not make the missing scene topics (/scene/*, /controller/phase): "
                        "the output holds exactly the source's intact messages")
    add_read_limit(r)
    r.set_defaults(handler=_cmd_recover)

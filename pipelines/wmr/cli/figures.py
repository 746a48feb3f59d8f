"""``wmr figures``: the paper's Figs. 9-12 and a region-of-attraction map as PNG files."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _cmd_figures(args: argparse.Namespace) -> int:
    from wmr.apps.figures import make_figures
    from wmr.infra.errors import ConfigError
    from wmr.infra.outputs import check_output

    if args.roa_grid < 0 or args.roa_headings < 1:
        raise ConfigError("--roa-grid", "needs N >= 0 and --roa-headings K >= 1",
                          "e.g. --roa-grid 9 --roa-headings 4, or --roa-grid 0 to skip it")

    check_output(args.out, "--out", "dir")

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    written = make_figures(Path(args.out), logs=Path(args.logs) if args.logs else None,
                           roa_grid=args.roa_grid, roa_headings=args.roa_headings,
                           progress=progress)
    for path in written:
        print(path)
    return 0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``figures`` sub-command."""
    from wmr.apps.figures import ROA_GRID, ROA_HEADINGS

    f = sub.add_parser(
        "figures", help="the paper's Figs. 9-12 and a region-of-attraction map as PNG files",
        description="Draw the paper's Figs. 9, 10, 11 and 12 from the logs of the fig9, fig10 "
                    "and fig11 scenarios (run now, into OUT/logs/, unless --logs has them), "
                    "and a map of the time to goal from a grid of start poses.  Prints the "
                    "path of each PNG file, one per line.")
    f.add_argument("--out", metavar="DIR", default="figures",
                   help="output folder (default: figures)")
    f.add_argument("--logs", metavar="DIR",
                   help="folder with the scenario logs (searched recursively)")
    f.add_argument("--roa-grid", type=int, default=ROA_GRID, metavar="N",
                   help=f"N x N start positions on [-10, 10] m around the goal (default "
                        f"{ROA_GRID}; 0 skips the map)")
    f.add_argument("--roa-headings", type=int, default=ROA_HEADINGS, metavar="K",
                   help=f"start headings per position, evenly spaced (default {ROA_HEADINGS})")
    f.set_defaults(handler=_cmd_figures)

"""``wmr fmu crosscheck --out DIR``: the FMUs with reference results in the FMI Cross-Check
layout (see :mod:`wmr.build.crosscheck`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _cmd(args: argparse.Namespace) -> int:
    from wmr.build.crosscheck import write_crosscheck
    from wmr.cli.building import build_for

    entries = write_crosscheck(build_for(args, args.fmu_dir), Path(args.out))
    # One exported-FMU folder a line on standard output, as `wmr fmu build` prints its FMUs;
    # what fmpy's re-import made of each on standard error.
    for entry in entries:
        print(entry.folder)
    for entry in entries:
        state = ("reference made on the host platform" if entry.passed is None else
                 "fmpy re-import passed" if entry.passed else "fmpy re-import FAILED")
        print(f"FMI {entry.fmi_version} {entry.fmi_type} {entry.platform}: {state}",
              file=sys.stderr)
    return 1 if any(e.passed is False for e in entries) else 0


def register(fmu_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``crosscheck`` to the ``wmr fmu`` actions."""
    from wmr.cli.building import add_platforms_option

    parser = fmu_sub.add_parser(
        "crosscheck", help="write the FMUs with reference results in the FMI Cross-Check layout",
        description="Build (or reuse) the FMUs and write, for each FMI version, interface and "
                    "platform, the FMI Cross-Check folder fmus/<fmi>/<cs|me>/<platform>/"
                    "wmr-cosim/<version>/wmr_robot/ (FMU, _in.csv, _ref.csv, _ref.opt, "
                    "ReadMe.md), and results/.../FMPy/... with fmpy's passed or failed marker "
                    "for the host platform.  Prints each FMU folder, one a line; exits 1 if "
                    "fmpy's re-import does not reproduce a reference.")
    parser.add_argument("--out", metavar="DIR", required=True, help="folder to write into")
    parser.add_argument("--fmu-dir", metavar="DIR", default=None,
                        help="where the FMUs are built or reused (default: the cache)")
    add_platforms_option(parser)
    parser.set_defaults(handler=_cmd)

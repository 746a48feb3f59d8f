"""What the commands that build FMUs share: ``--platforms``, the build with its progress on
standard error, and its errors named by the command's options."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from wmr.infra.errors import ConfigError

if TYPE_CHECKING:
    from wmr.build.fmus import BuildResult


def build_progress(line: str) -> None:
    """A build's progress line on standard error (standard output is for results)."""
    print(f"wmr: {line}", file=sys.stderr, flush=True)


def add_platforms_option(parser: argparse.ArgumentParser) -> None:
    """``--platforms host|all|LIST`` of the commands that build FMUs for other tools."""
    parser.add_argument(
        "--platforms", metavar="host|all|LIST", default="all",
        help="binaries to build: all (default: x86_64-linux, aarch64-linux, x86_64-windows, "
             "x86_64-darwin, aarch64-darwin with the ziglang package, the host with gcc), "
             "host (this machine only: seconds), or a comma-separated list of those names")


def build_for(args: argparse.Namespace, out: str | None) -> BuildResult:
    """The FMUs for a command's ``--platforms``, reporting progress; an unknown platform or
    a folder that cannot be made is the option's one-line error."""
    from wmr.build.fmus import build_fmus

    try:
        return build_fmus(out, force=getattr(args, "force", False), platforms=args.platforms,
                          on_build=build_progress)
    except ConfigError as exc:
        option = {"platforms": "--platforms", "out_dir": "--out"}.get(exc.field)
        if option is None:
            raise
        raise ConfigError(option, exc.problem, exc.fix) from None


__all__ = ["add_platforms_option", "build_for", "build_progress"]

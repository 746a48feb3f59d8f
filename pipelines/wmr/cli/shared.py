"""What the commands that drive an FMU share: the ``--fmi``/``--fmu`` options, progress lines
on standard error, and one-line JSON results."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any


def add_fmu_options(p: argparse.ArgumentParser) -> None:
    """Add ``--fmi`` and ``--fmu`` to a command."""
    p.add_argument("--fmi", type=int, choices=(2, 3), default=3,
                   help="FMI version of the FMU to drive (default 3)")
    p.add_argument("--fmu", metavar="FILE.fmu",
                   help="drive this FMU instead of the project's own build")


def fmu_path(args: argparse.Namespace) -> Path:
    """The FMU ``--fmu`` names, or the project's own build for ``--fmi``."""
    from wmr.apps.run import default_fmu

    return Path(args.fmu) if args.fmu else default_fmu(args.fmi)


def progress_line(line: str) -> None:
    """A long step's progress line on standard error (standard output is for results)."""
    print(f"wmr: {line}", file=sys.stderr, flush=True)


def json_line(obj: Any) -> str:
    """One line of JSON, NaN/inf as null."""

    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [clean(x) for x in v]
        return v

    return json.dumps(clean(obj), allow_nan=False)

"""What the commands share: the ``--fmi``/``--fmu`` options, progress lines on standard error,
one-line JSON results, and errors that name the command's options."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import re
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from wmr.infra.errors import ConfigError


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


def _in_options(text: str, options: Mapping[str, str]) -> str:
    """``text`` with the request's ``field=VALUE`` written as ``--option VALUE``, and the
    fields with an underscore (never a plain word) as their options."""
    for name, option in options.items():
        text = re.sub(rf"(?<![\w-]){re.escape(name)}=", f"{option} ", text)
        if "_" in name:
            text = re.sub(rf"(?<![\w-]){re.escape(name)}(?![\w=])", option, text)
    return text


@contextlib.contextmanager
def errors_as_options(options: Mapping[str, str]) -> Iterator[None]:
    """Errors raised inside name the fields of ``options`` (a request's field -> this
    command's option) as the options, in the field and in the problem and fix
    (:func:`_in_options`): the layers below name their inputs by the API's keywords, the
    command line by its options."""
    try:
        yield
    except ConfigError as exc:
        # a part of a field (``goal y``) is the same part of its option (``--goal y``)
        head, sep, part = exc.field.partition(" ")
        option = options.get(exc.field) or (f"{options[head]} {part}"
                                            if sep and head in options else None)
        if option is None:
            raise
        raise ConfigError(option, _in_options(exc.problem, options),
                          _in_options(exc.fix, options)) from None

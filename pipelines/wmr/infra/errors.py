"""Typed errors.  The command line prints any :class:`WmrError` as one line, no traceback."""

from __future__ import annotations


class WmrError(Exception):
    """Base of every error the user can act on."""


_MAX_PROBLEM = 300


class ConfigError(WmrError, ValueError):
    """Bad user input: names the field and says how to fix it.

    Parameters
    ----------
    field
        Dotted path of the offending field, e.g. ``"goal.x_m"`` or ``"gains.K_ps"``.
    problem
        What is wrong with the value.
    fix
        What the user should do instead.
    """

    def __init__(self, field: str, problem: str, fix: str = "") -> None:
        if len(problem) > _MAX_PROBLEM:  # a 200k-element value must not make a 1 MB line
            problem = f"{problem[:_MAX_PROBLEM]}... ({len(problem)} characters)"
        self.field = field
        self.problem = problem
        self.fix = fix
        msg = f"{field}: {problem}"
        if fix:
            msg += f" ({fix})"
        super().__init__(msg)


class BuildError(WmrError):
    """The Modelica-to-FMU build failed."""


class FmuError(WmrError):
    """An FMU call returned an error status, or an FMU archive is unusable."""


class LogError(WmrError):
    """An MCAP log cannot be written or read."""


class DiskFullError(WmrError):
    """An output cannot be written: no space left on its device (``ENOSPC``, ``EDQUOT``)."""


class ClusterError(WmrError):
    """The Dask cluster of a batch went away or cannot run it (its scheduler died or cannot be
    reached, it has no workers): the runs it had are not results, and are run again on resume.

    Parameters
    ----------
    problem
        What happened, naming the scheduler (``the Dask scheduler tcp://... went away``).
    fix
        What brings the cluster back (``start a scheduler``).
    cause
        How it showed (``FutureCancelledError: ... scheduler-connection-lost``), or ``""``.
    """

    def __init__(self, problem: str, fix: str, cause: str = "") -> None:
        self.problem = problem
        self.fix = fix
        self.cause = cause
        super().__init__(f"{problem}{f' ({cause})' if cause else ''}; {fix}")

"""The log of a run, as a protocol: what a run writes, whatever the format.

A run's log is opened with a :class:`LogHeader` (the run's metadata, its goal, its
attachments and the typed values a log's drawing needs), receives the run's rows in blocks
(:meth:`RunLog.write_block`, the :class:`~wmr.core.closedloop.BlockSink` the loop writes to),
the run's sensing (:meth:`RunLog.write_sensing`) and is closed with the run's result record
(:meth:`RunLog.close`).  A run that raises leaves the log's ``with`` block by its exception:
the log is closed with status ``failed`` and the error (:func:`failed_result`), and is
readable.

A :data:`LogOpener` opens one log from a header.  Two implementations:

* MCAP, the format of ``wmr run`` and ``wmr batch``:
  :class:`wmr.adapters.mcap.writer.McapOpener` opens a
  :class:`wmr.adapters.mcap.writer.RunLogWriter`;
* memory, here: :class:`MemoryLog` keeps what it was given (the tests' recorder, and a run
  whose rows a caller wants as arrays without a file), :class:`MemoryOpener` opens them.

A new format implements :class:`RunLog` and an opener (docs/architecture.md).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import TracebackType
from typing import TYPE_CHECKING, Final, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from wmr.core.plant import RobotParams
from wmr.core.sensing import SensingRecord
from wmr.core.signals import SIGNALS
from wmr.infra.errors import LogError

if TYPE_CHECKING:
    from wmr.core.runspec import RunSpec

#: The result a log is closed with when its run left the log's ``with`` block without one.
NO_RESULT: Final = "the run ended without a result"


@dataclass(frozen=True)
class LogHeader:
    """What a run's log is opened with.

    Attributes
    ----------
    run
        The ``run`` metadata record (docs/formats.md): name, scenario, start, goal, params,
        gains, FMU, software version, ...; a format stores values that are not strings as it
        documents (MCAP: JSON).
    goal
        ``(x_m, y_m, theta_rad)`` of the goal, m and rad.
    attachments
        ``(name, media_type, data)`` of each attached file, in order (the FMU's
        ``modelDescription.xml``, the run's effective scenario).
    half_track_m
        Half the robot's track ``L``, m (the drawn outline).
    wheel_radius_m
        The wheel radius ``r``, m (the drawn outline).
    stop_radius_m
        The run's stop radius, m (the goal's ring and the control phase); ``None``: none
        drawn.
    """

    run: Mapping[str, object]
    goal: tuple[float, float, float]
    attachments: tuple[tuple[str, str, bytes], ...] = ()
    half_track_m: float = RobotParams.L
    wheel_radius_m: float = RobotParams.r
    stop_radius_m: float | None = None

    @classmethod
    def of_spec(cls, spec: RunSpec, run: Mapping[str, object] | None = None,
                attachments: tuple[tuple[str, str, bytes], ...] = ()) -> LogHeader:
        """The header of a closed-loop run of ``spec``: its goal, robot and stop radius, with
        ``run`` as the metadata record (default: the spec's name only)."""
        return cls(run={"name": spec.name} if run is None else run,
                   goal=(spec.goal.x_m, spec.goal.y_m, spec.goal.heading_rad),
                   attachments=attachments, half_track_m=spec.params.L,
                   wheel_radius_m=spec.params.r, stop_radius_m=spec.stop_radius_m)

    def attachment_map(self) -> dict[str, tuple[str, bytes]]:
        """The attachments as ``{name: (media_type, data)}``, in order."""
        return {name: (media_type, data) for name, media_type, data in self.attachments}


def failed_result(exc: BaseException | None) -> dict[str, str]:
    """The result a log is closed with when its run raised ``exc`` (or, ``None``, left the
    log's ``with`` block without closing it): status ``failed`` and the error."""
    error = NO_RESULT if exc is None else f"{type(exc).__name__}: {exc}"
    return {"status": "failed", "error": error}


@runtime_checkable
class RunLog(Protocol):
    """The log of one run, open (a :class:`~wmr.core.closedloop.BlockSink` and more).

    A context manager: leaving its ``with`` block without :meth:`close` closes it with
    :func:`failed_result` of the exception (the log is then finished and readable; an error
    of the log's own while closing never hides the run's exception).
    """

    @property
    def location(self) -> str | None:
        """Where the log is kept (a file's path), ``None`` when not in a file: the
        ``mcap`` field of the result record."""
        ...

    def write_block(self, t_ns: npt.NDArray[np.int64],
                    block: npt.NDArray[np.float64]) -> None:
        """Rows of the run: ``t_ns`` (n,) ns from the start, non-decreasing across calls;
        ``block`` (n, len(SIGNALS)) laid out as :data:`wmr.core.signals.SIGNALS`.  The
        arrays are reused by the caller after the call: a log copies what it keeps."""
        ...

    def write_sensing(self, record: SensingRecord) -> None:
        """The run's sensor fixes and estimates (runs with sensors; before :meth:`close`)."""
        ...

    def close(self, result: Mapping[str, object]) -> None:
        """Finish the log with the run's result record (``docs/results.md``); writing after
        it, or closing twice, raises :class:`~wmr.infra.errors.LogError`."""
        ...

    def discard(self, result: Mapping[str, object]) -> None:
        """Close the log and drop it: the run's log is not kept (a ``failed`` policy's run
        that converged after its rows were spilled)."""
        ...

    def __enter__(self) -> RunLog: ...

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None: ...


#: Opens the log of one run from its header.
LogOpener = Callable[[LogHeader], RunLog]


class MemoryLog:
    """A run's log in memory: what a run wrote, as arrays (the recorder of the tests).

    Parameters
    ----------
    header
        What the log was opened with (default: an empty header, a goal at the origin: a
        sink of a loop run alone).

    Attributes
    ----------
    header
        As given.
    sensing
        The run's sensing, if written.
    result
        The result record the log was closed with (``None`` while open).
    closed
        Whether :meth:`close` (or the ``with`` block's end) closed it.
    discarded
        Whether :meth:`discard` closed it.
    """

    def __init__(self, header: LogHeader | None = None) -> None:
        self.header = header if header is not None else LogHeader(run={}, goal=(0.0, 0.0, 0.0))
        self.sensing: SensingRecord | None = None
        self.result: dict[str, object] | None = None
        self.closed = False
        self.discarded = False
        self._t: list[npt.NDArray[np.int64]] = []
        self._rows: list[npt.NDArray[np.float64]] = []

    @property
    def location(self) -> str | None:
        """``None``: the log is in memory, not in a file."""
        return None

    @property
    def t_ns(self) -> npt.NDArray[np.int64]:
        """Every row's time, ns, shape ``(n,)`` (a new array)."""
        return np.concatenate(self._t) if self._t else np.zeros(0, np.int64)

    @property
    def block(self) -> npt.NDArray[np.float64]:
        """Every row, shape ``(n, len(SIGNALS))`` (a new array)."""
        return (np.concatenate(self._rows) if self._rows
                else np.zeros((0, len(SIGNALS)), np.float64))

    @property
    def rows(self) -> int:
        """How many rows were written."""
        return sum(len(t) for t in self._t)

    @property
    def block_sizes(self) -> tuple[int, ...]:
        """The rows of each block as it was written (empty ones too), in order."""
        return tuple(len(t) for t in self._t)

    def _check_open(self, what: str) -> None:
        if self.closed:
            raise LogError(f"memory log of {self.header.run.get('name', 'a run')!s}: "
                           f"{what} after close")

    def write_block(self, t_ns: npt.NDArray[np.int64],
                    block: npt.NDArray[np.float64]) -> None:
        """Keep a copy of the rows (the caller reuses its arrays).

        Raises
        ------
        LogError
            The log is closed, or ``block`` is not ``(len(t_ns), len(SIGNALS))``.
        """
        self._check_open("write_block")
        t = np.array(t_ns, dtype=np.int64, copy=True)
        x = np.array(block, dtype=np.float64, copy=True)
        if t.ndim != 1 or x.shape != (len(t), len(SIGNALS)):
            raise LogError(f"block must have shape ({len(t)}, {len(SIGNALS)}) for t_ns of "
                           f"shape {t.shape}, got {x.shape}")
        self._t.append(t)
        self._rows.append(x)

    def write_sensing(self, record: SensingRecord) -> None:
        """Keep a deep copy of the run's sensing."""
        self._check_open("write_sensing")
        self.sensing = copy.deepcopy(record)

    def close(self, result: Mapping[str, object]) -> None:
        """Keep a copy of the result record; the log takes nothing more."""
        if self.closed:
            raise LogError(f"memory log of {self.header.run.get('name', 'a run')!s}: "
                           "closed twice")
        self.closed = True
        self.result = dict(result)

    def discard(self, result: Mapping[str, object]) -> None:
        """Close the log and mark it dropped (its contents stay readable here)."""
        self.close(result)
        self.discarded = True

    def __enter__(self) -> MemoryLog:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if not self.closed:
            self.close(failed_result(exc))


@dataclass
class MemoryOpener:
    """A :data:`LogOpener` of :class:`MemoryLog` that keeps every log it opened.

    Attributes
    ----------
    logs
        The logs opened, in order.
    """

    logs: list[MemoryLog] = field(default_factory=list)

    def __call__(self, header: LogHeader) -> MemoryLog:
        log = MemoryLog(header)
        self.logs.append(log)
        return log

    @property
    def last(self) -> MemoryLog:
        """The last log opened.

        Raises
        ------
        LookupError
            None was opened (a run without a log).
        """
        if not self.logs:
            raise LookupError("no log was opened")
        return self.logs[-1]


__all__ = ["NO_RESULT", "LogHeader", "LogOpener", "MemoryLog", "MemoryOpener", "RunLog",
           "failed_result"]

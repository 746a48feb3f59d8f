"""Progress of long work over a count of items (a batch's runs, the benchmark's cases).

One bar on a terminal (tqdm, as before); where stderr is not a terminal (a CI log, ``nohup``,
a file) a line every :data:`LINE_INTERVAL_S` instead of nothing until the end, with the count
and the time left; in a notebook one bar (``tqdm.auto``: a widget when ipywidgets is there)
redrawn at most every :data:`NOTEBOOK_INTERVAL_S`, not a new line of text per redraw.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any, Protocol, TextIO

#: Seconds between two progress lines where stderr is not a terminal.
LINE_INTERVAL_S = 10.0
#: Least seconds between two redraws of a notebook's bar.
NOTEBOOK_INTERVAL_S = 1.0


class CountProgress(Protocol):
    """What the callers use of a tqdm bar (and :class:`ProgressLines` has)."""

    n: float

    def update(self, n: float = 1) -> bool | None: ...

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None: ...

    def close(self) -> None: ...


def _duration(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``2 h 07 min``."""
    s = round(seconds)
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


class ProgressLines:
    """A line ``wmr: DESC: k/N UNITs (p %), POSTFIX; T elapsed, about T left`` on ``file`` at
    most every ``interval_s``, and one at the end when any was printed (work shorter than the
    interval prints nothing, as before).

    The time left is from the rate of this invocation's items (``initial`` done before are not
    counted in it: a resumed batch does not look faster than it is).
    """

    def __init__(self, total: int, desc: str, unit: str, *, initial: int = 0,
                 file: TextIO | None = None, interval_s: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.total = total
        self.desc = desc
        self.unit = unit
        self.n: float = initial
        self._initial = initial
        self._postfix = ""
        self._file = file
        self._interval_s = LINE_INTERVAL_S if interval_s is None else interval_s
        self._clock = clock
        self._t0 = clock()
        self._last = self._t0
        self._printed = False
        self._printed_n: float = self.n

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self._postfix = s

    def update(self, n: float = 1) -> bool | None:
        self.n += n
        now = self._clock()
        if now - self._last >= self._interval_s:
            self._print(now)
        return None

    def close(self) -> None:
        if self._printed and self._printed_n != self.n:  # the count the last line missed
            self._print(self._clock())

    def line(self, now: float) -> str:
        """The progress line at clock time ``now``."""
        done = int(self.n)
        pct = f" ({100.0 * done / self.total:.0f} %)" if self.total else ""
        post = f", {self._postfix}" if self._postfix else ""
        elapsed = now - self._t0
        here = self.n - self._initial
        left = ""
        if 0 < here and done < self.total:
            left = f", about {_duration(elapsed / here * (self.total - done))} left"
        return (f"wmr: {self.desc}: {done}/{self.total} {self.unit}s{pct}{post}; "
                f"{_duration(elapsed)} elapsed{left}")

    def _print(self, now: float) -> None:
        print(self.line(now), file=self._file or sys.stderr, flush=True)
        self._last = now
        self._printed = True
        self._printed_n = self.n


def _in_notebook() -> bool:
    return "ipykernel" in sys.modules


def count_progress(total: int, desc: str, unit: str, progress: bool | None, *,
                   initial: int = 0, **bar: Any) -> CountProgress:
    """The progress of ``total`` items on stderr.

    Parameters
    ----------
    total, desc, unit, initial
        Items in all, what they are of and called, how many were done before.
    progress
        ``False``: nothing; ``None``: a bar on a terminal, else a line every
        :data:`LINE_INTERVAL_S`; ``True``: the same, and a bar in a notebook.
    bar
        More keywords of the terminal's tqdm bar (``smoothing``, ``dynamic_ncols``...).
    """
    from tqdm import tqdm

    if progress is False:
        return tqdm(total=total, disable=True)
    if sys.stderr.isatty():
        return tqdm(total=total, initial=initial, unit=unit, desc=desc, file=sys.stderr,
                    **bar)
    if progress and _in_notebook():
        from tqdm.auto import tqdm as auto

        return auto(total=total, initial=initial, unit=unit, desc=desc,
                    mininterval=NOTEBOOK_INTERVAL_S)
    return ProgressLines(total, desc, unit, initial=initial)


__all__ = ["LINE_INTERVAL_S", "NOTEBOOK_INTERVAL_S", "CountProgress", "ProgressLines",
           "count_progress"]

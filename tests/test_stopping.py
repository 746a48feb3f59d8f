"""Stopping and crashing runs (issue 28, items 4 and 13).

* The log writer's write-then-forget step (a chunk written, its rows dropped from the pending
  list) cannot be split by an exception: one raised at any line of it (a signal handler's
  ``KeyboardInterrupt``, a full disk) leaves every row either on disk once or still pending,
  never both (a SIGTERM between the two used to make ``close()`` write the same rows again).
* ``wmr run`` answers SIGINT and SIGTERM within a second while the FMU loops in C, and an FMU
  that crashes the process is one line and a finished log with a ``failed`` result.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

import wmr.adapters.mcap.writer as writer_module
import wmr.infra.durable as durable_module
from wmr.adapters.mcap import RunLogWriter, read_run
from wmr.adapters.mcap.schemas import STEP_TOPICS
from wmr.core.signals import SIGNALS

GOAL = (2.0, 1.0, 0.0)
STEP_NS = 10_000_000  # 100 Hz: a chunk (1 s) every 100 rows
BLOCK = 30  # rows per write_block: chunks end inside blocks
TOPICS = [t.topic for t in STEP_TOPICS]


def _rows(n: int) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    t = np.arange(n, dtype=np.int64) * STEP_NS
    x = np.random.default_rng(0).normal(size=(n, len(SIGNALS)))
    return t, x


class _Interrupt:
    """A tracer that raises ``KeyboardInterrupt`` at the ``at``-th line executed in the
    writer's and the durable file's code (as a signal handler does between two bytecodes),
    once; ``lines`` counts the lines seen."""

    FILES = (writer_module.__file__, durable_module.__file__)

    def __init__(self, at: int) -> None:
        self.at, self.lines, self.fired = at, 0, False

    def _local(self, frame: FrameType, event: str, arg: object) -> Callable[..., Any] | None:
        if event == "line" and not self.fired:
            self.lines += 1
            if self.lines == self.at:
                self.fired = True
                raise KeyboardInterrupt
        return self._local

    def __call__(self, frame: FrameType, event: str, arg: object) -> Callable[..., Any] | None:
        return self._local if frame.f_code.co_filename in self.FILES else None


def _interrupted_log(path: Path, at: int) -> tuple[_Interrupt, int]:
    """Write 250 rows in blocks, the tracer armed around each ``write_block``; on the
    interrupt, close the log as ``wmr run`` does.  Returns the tracer and the rows handed
    over before the interrupted call."""
    t, x = _rows(250)
    trace = _Interrupt(at)
    handed = 0
    with RunLogWriter(path, run={"name": "r"}, goal=GOAL) as w:
        try:
            for i in range(0, len(t), BLOCK):
                sys.settrace(trace)
                try:
                    w.write_block(t[i:i + BLOCK], x[i:i + BLOCK])
                finally:
                    sys.settrace(None)
                handed = i + BLOCK
        except KeyboardInterrupt:
            w.close({"status": "failed", "error": "KeyboardInterrupt"})
    return trace, handed


def test_an_interrupt_at_any_line_of_a_chunk_write_never_repeats_rows(tmp_path: Path) -> None:
    """Issue 28 item 13: the rows of a chunk were dropped from the pending list only after the
    chunk was written, so an exception between the two wrote them again at ``close()``
    (``test_sigterm_stops_wmr_run_like_ctrl_c`` saw 100 messages repeating log times).  An
    interrupt at every line the writer runs while taking the blocks: each log holds each row
    once, in order, the rows of every call that returned among them."""
    t_all = _rows(250)[0]
    at = 0
    while True:  # every line, until the writer runs out of lines before the interrupt
        at += 1
        out = tmp_path / f"at{at}.mcap"
        trace, handed = _interrupted_log(out, at)
        if not trace.fired:
            break
        run = read_run(out)
        assert not run.truncated, (at, run.warnings)
        # the messages as written (read_run joins the topics by log time, which would hide a
        # repeated row), on every per-step topic
        with out.open("rb") as f:
            times = [m.log_time for _, _, m in make_reader(f).iter_messages(topics=TOPICS)]
        logged = np.array(times[::len(TOPICS)])
        assert np.all(np.diff(logged) > 0), f"a row repeated after an interrupt at line {at}"
        assert np.array_equal(np.sort(times), np.repeat(logged, len(TOPICS)))
        assert np.array_equal(run.t_ns, logged)
        assert np.array_equal(logged, t_all[:len(logged)]), f"interrupt at line {at}"
        assert handed <= len(logged) <= handed + BLOCK, f"interrupt at line {at}"
        out.unlink()
    assert at > 200  # the lines of 9 calls and 2 chunk writes were all tried

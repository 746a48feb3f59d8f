"""``wmr run`` in a child process that its parent watches: an FMU that loops in C or crashes
the process still ends as one line, a ``failed`` record and a finished log.

A signal only reaches Python between two bytecodes: while an FMU spins in ``fmi3DoStep`` the
run process cannot answer SIGINT or SIGTERM, and an FMU that writes through NULL kills it
with SIGSEGV before any Python runs again.  So the run goes on in a forked child (the same
code, at the same speed: nothing is added to its loop) and the parent, which only waits:

* forwards SIGINT and SIGTERM to the child (unless the child says it got the signal itself, as
  after a Ctrl-C, which reaches the whole process group), and when the child has not
  answered within :data:`GRACE_S` (its handler tells the parent through a pipe: the run is
  in Python, finishing its log), kills it and records the run as interrupted while the FMU
  was in a call;
* sees a child that died of a signal it did not send (SIGSEGV, SIGBUS, SIGFPE, SIGABRT, the
  OOM killer's SIGKILL) as a crash.

Either way the child's ``X.mcap.partial`` (the child says when it opened it) is made a
finished log with a ``failed`` result (:func:`wmr.adapters.mcap.recover.recover_log`: the
chunks flushed so far, at most the last second of simulation lost), its FMU folder is
removed, and the caller prints the one line.  A child that ends by itself (converged,
failed, refused input, interrupted in Python) is the whole answer: its exit status is
returned, and it printed its own lines.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import select
import signal
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any, Final

#: How long the run may take to answer SIGINT or SIGTERM before it is taken to be stuck in
#: a call into the FMU and killed, s.
GRACE_S: Final = 0.5
_STOP_SIGNALS: Final = (signal.SIGINT, signal.SIGTERM)
_PR_SET_PDEATHSIG: Final = 1


class RunChannel:
    """The child's side of the pipe to its parent: what the parent needs to finish the run's
    log if the child cannot."""

    def __init__(self, fd: int) -> None:
        self._fd = fd

    def _send(self, message: dict[str, Any]) -> None:
        os.write(self._fd, json.dumps(message).encode() + b"\n")

    def log_opened(self, path: Path, name: str) -> None:
        """The run ``name`` is writing its log to ``path`` (its ``.partial`` file)."""
        self._send({"log": str(path), "name": name})

    def signalled(self, signum: int) -> None:
        """The run's own handler got ``signum``: it is in Python and stopping (called from
        the signal handler: one write to a pipe)."""
        self._send({"signal": signum})


@dataclass(frozen=True)
class Abandoned:
    """A run whose process the parent had to end (or that died): the record to print.

    Attributes
    ----------
    record
        The run's result record (``docs/results.md``): status ``failed``, the message, the
        finished log's path in ``mcap`` (``None`` when the run had opened none).
    stop_signal
        The signal the run did not answer (its exit status is ``128 + stop_signal``), or
        ``None`` for a crash (exit status 1).
    """

    record: dict[str, Any]
    stop_signal: int | None


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def supervise(child: Callable[[RunChannel], int], grace_s: float = GRACE_S) -> int | Abandoned:
    """Run ``child(channel)`` in a forked process and wait for it.

    Returns
    -------
    int or Abandoned
        The child's exit status when it ended by itself; an :class:`Abandoned` run when it
        died of a signal or did not answer a stop signal within ``grace_s``.
    """
    read_fd, write_fd = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    parent = os.getpid()
    pid = os.fork()
    if pid == 0:  # the run process: never returns into the parent's stack
        code = 1
        try:
            os.close(read_fd)
            _die_with_parent(parent)
            code = child(RunChannel(write_fd))
        except SystemExit as exc:  # argparse, sys.exit: their status, as without a parent
            code = exc.code if isinstance(exc.code, int) else 1
        except BaseException:  # only with --debug does the command raise: its traceback
            traceback.print_exc()
            code = 1
        finally:
            for stream in (sys.stdout, sys.stderr):
                with contextlib.suppress(Exception):  # a closed pipe: nothing to flush to
                    stream.flush()
            os._exit(code)
    os.close(write_fd)
    return _watch(pid, read_fd, grace_s)


def _die_with_parent(parent: int) -> None:
    """End this process (SIGKILL) when its parent ends, even killed outright (``kill -9`` of
    ``wmr run``): no orphan goes on writing the log.  Linux's ``PR_SET_PDEATHSIG``; elsewhere
    the run outlives a parent killed outright, as it did before it had one."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (AttributeError, OSError):
        return
    if os.getppid() != parent:  # the parent died before the call
        os._exit(1)


def _watch(pid: int, read_fd: int, grace_s: float) -> int | Abandoned:
    """The parent's side: forward stop signals, wait for the child, end it when stuck."""
    got: list[tuple[int, float]] = []  # the stop signals that reached the parent, and when

    def on_signal(signum: int, frame: FrameType | None) -> None:
        got.append((signum, time.monotonic()))

    old = {s: signal.signal(s, on_signal) for s in _STOP_SIGNALS}
    try:
        pidfd: int | None = os.pidfd_open(pid)
    except (AttributeError, OSError):  # before Linux 5.3: the wait below polls
        pidfd = None
    log: dict[str, str] = {}
    answered: int | None = None  # the signal the child's own handler took
    forwarded = killed = False
    buffer = b""
    try:
        while True:
            watched = [read_fd] if pidfd is None else [read_fd, pidfd]
            ready, _, _ = select.select(watched, [], [], 0.05)
            if read_fd in ready:
                data = os.read(read_fd, 65536)
                buffer += data
                *lines, buffer = buffer.split(b"\n")
                for line in lines:
                    message = json.loads(line)
                    if "log" in message:
                        log = message
                    elif answered is None:
                        answered = int(message["signal"])
            ended, status = os.waitpid(pid, os.WNOHANG)
            if ended:
                break
            if got and answered is None and not killed:
                signum, at = got[0]
                if not forwarded:  # (a Ctrl-C reaches the child too: it takes one of the two)
                    os.kill(pid, signum)
                    forwarded = True
                if time.monotonic() - at >= grace_s:
                    os.kill(pid, signal.SIGKILL)
                    killed = True
    finally:
        os.close(read_fd)
        if pidfd is not None:
            os.close(pidfd)
        for s, handler in old.items():
            signal.signal(s, handler)
    if os.WIFEXITED(status):
        # a stop signal the run ended before taking still sets the exit status, as it would
        # have without a parent (wmr.cli: 128 + the first signal)
        return 128 + got[0][0] if got and answered is None else os.WEXITSTATUS(status)
    died_of = os.WTERMSIG(status)
    # (a signal forwarded before the child had its handlers, just after the fork, ends it)
    if killed or (forwarded and died_of == got[0][0]):
        stop: int | None = got[0][0]
        name = _signal_name(got[0][0])
        message = (f"interrupted ({name}) while the FMU was in a call: it did not return "
                   f"within {grace_s:g} s, so the run process was killed" if killed
                   else f"interrupted ({name}) while the run was starting")
    else:
        stop = None
        message = (f"the run process died of {_signal_name(died_of)} (a crash in the FMU, "
                   "or the process was killed)")
    return Abandoned(_finish_log(log, message), stop)


def _finish_log(log: dict[str, str], message: str) -> dict[str, Any]:
    """The ``failed`` record of a run whose process is gone, its partial log (if it opened
    one) recovered into place with that record as its result, its FMU folder removed."""
    from wmr.adapters.fmi.slave import remove_stale_folders
    from wmr.adapters.mcap import read_run
    from wmr.adapters.mcap.recover import recover_log
    from wmr.core.record import RunFigures, record
    from wmr.infra.durable import partial_path

    remove_stale_folders()  # the dead run's: its lock died with it
    result = record(RunFigures(
        name=log.get("name", ""), status="failed", message=message, final_position_error_m=None,
        final_heading_error_rad=None, time_to_goal_s=None, path_length_m=None, energy_net_j=None,
        energy_positive_j=None, energy_abs_j=None, torque_sq_integral_n2m2s=None,
        peak_torque_nm=None, steps=0, estimated_final_position_error_m=None,
        estimated_final_heading_error_rad=None))
    path = Path(log["log"]) if "log" in log else None
    if path is None or not partial_path(path).exists():
        return result
    result["mcap"] = str(path)
    result["steps"] = read_run(partial_path(path)).n_steps  # the rows its chunks hold
    recover_log(partial_path(path), path, overwrite=True, result=result)
    return result


__all__ = ["GRACE_S", "Abandoned", "RunChannel", "supervise"]

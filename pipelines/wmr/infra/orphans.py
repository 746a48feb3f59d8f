"""A process that ends when another one does: a batch's workers and a Dask task's retry
never outlive the process that gave them their runs."""

from __future__ import annotations

import os
import select
import threading
import time
from typing import Final

#: Exit status of a process whose watched process had gone.
ORPHANED: Final = 4
#: Windows, where ``os.kill(pid, 0)`` ends the process instead of probing it.
_ON_WINDOWS: Final = os.name == "nt"


def die_with(batch_pid: int) -> None:
    """End this worker (or a Dask task's retry, :mod:`wmr.apps.batch.retry`) as soon as the
    batch process ``batch_pid`` (the Dask worker) is gone, even killed by SIGKILL: an orphan
    must not go on writing into a folder that a resumed batch uses.

    The worker's parent is the forkserver, not the batch process, and the forkserver outlives
    the batch while workers hold its liveness pipe, so ``PR_SET_PDEATHSIG`` cannot do this.
    A daemon thread waits on a pidfd of the batch process (Linux >= 5.3), else polls it;
    on Windows nothing watches (its ``os.kill(pid, 0)`` would end the batch process, a Dask
    worker there: a retry outlives a worker killed outright).
    """
    if _ON_WINDOWS:
        return

    def watch() -> None:
        try:
            fd = os.pidfd_open(batch_pid)
        except (AttributeError, OSError):
            fd = None
        if fd is not None:
            select.select([fd], [], [])  # readable when the process has ended
        else:
            while True:
                time.sleep(0.5)
                try:
                    os.kill(batch_pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:  # alive, someone else's: cannot be ours
                    continue
        os._exit(ORPHANED)

    threading.Thread(target=watch, name="wmr-die-with-batch", daemon=True).start()


__all__ = ["ORPHANED", "die_with"]

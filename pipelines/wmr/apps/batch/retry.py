"""The process of a Dask task's retry (:func:`wmr.apps.batch.worker.run_alone`):
``python -m wmr.apps.batch.retry PID``, its pickled arguments on stdin, its result, pickled,
in the file they name; it ends with the process ``PID`` (the Dask worker that started it)."""

from __future__ import annotations

import pickle
import sys
from pathlib import Path
from typing import BinaryIO

from wmr.apps.batch.worker import PlantHolder, block_on
from wmr.infra.orphans import die_with


def main(argv: list[str], stdin: BinaryIO) -> None:
    """Run the block of the job read from ``stdin`` on a plant of its own; ``argv[1]`` is the
    worker's process id."""
    die_with(int(argv[1]))
    # the job comes from the worker that started this process, running this package
    block, fmu_path, attachment, out_dir, var_map, result = pickle.loads(stdin.read())
    holder = PlantHolder(Path(fmu_path), var_map)
    try:
        done = block_on(holder, block, None if attachment is None else Path(attachment),
                        out_dir)
    finally:
        holder.close()
    Path(result).write_bytes(pickle.dumps(done))


if __name__ == "__main__":
    main(sys.argv, sys.stdin.buffer)

"""The process of a Dask task's retry (:func:`wmr.apps.batch.worker.run_alone`):
``python -m wmr.apps.batch.retry PID``, its pickled arguments on stdin; it runs its runs one
after the other and appends each one's result to the file they name as the run ends
(:func:`~wmr.apps.batch.worker.write_frame`), and ends with the process ``PID`` (the Dask
worker that started it)."""

from __future__ import annotations

import pickle
import sys
from dataclasses import replace
from pathlib import Path
from typing import BinaryIO

from wmr.apps.batch.worker import PlantHolder, block_on, write_frame
from wmr.infra.orphans import die_with


def main(argv: list[str], stdin: BinaryIO) -> None:
    """Run the runs of the job read from ``stdin`` on a plant of its own, a result each;
    ``argv[1]`` is the worker's process id."""
    die_with(int(argv[1]))
    # the job comes from the worker that started this process, running this package
    block, fmu_path, attachment, out_dir, var_map, results, batch_dir = pickle.loads(
        stdin.read())
    holder = PlantHolder(Path(fmu_path), var_map)
    try:
        with open(results, "ab") as f:
            for index in block.indices:
                done = block_on(holder, replace(block, indices=[index]),
                                None if attachment is None else Path(attachment), out_dir,
                                batch_dir)
                write_frame(f, done)
                if done.stop is not None:  # the batch stops: no run after
                    break
    finally:
        holder.close()


if __name__ == "__main__":
    main(sys.argv, sys.stdin.buffer)

"""Cost of one 10 ms co-simulation step of this tree's FMUs against those of a git revision.

Both sets of FMUs are stepped in turn (2000 steps each, 30 rounds), through fmpy's API and
through :meth:`wmr.adapters.fmi.robot.FmuPlant.step`, and timed in process CPU time, so that a
loaded machine (other processes taking the cores) biases neither side.  Prints medians and the ratio
this tree / revision.

Run: ``python benchmarks/fmu_step_ab.py [REVISION]`` (default ``main``).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from fmu_step import H, _fmpy_stepper
from wmr.adapters.fmi.robot import FmuPlant
from wmr.build.fmus import build_fmus
from wmr.core.plant import Pose, RobotParams
from wmr.infra import paths

N_STEPS, ROUNDS = 2000, 30


def build_at(revision: str, tmp: Path) -> Path:
    """Build the FMUs of ``revision`` (its own build code and sources) into ``tmp/fmu``."""
    root = Path(paths.__file__).resolve().parents[2]
    archive = subprocess.run(["git", "-C", str(root), "archive", revision], check=True,
                             capture_output=True).stdout
    tree = tmp / "tree"
    tree.mkdir()
    (tmp / "tree.tar").write_bytes(archive)
    with tarfile.open(tmp / "tree.tar") as tar:
        tar.extractall(tree, filter="data")
    env = {**os.environ, "PYTHONPATH": str(tree / "pipelines")}
    subprocess.run([sys.executable, "-c",
                    f"from wmr.build.fmus import build_fmus; build_fmus({str(tmp / 'fmu')!r})"],
                   check=True, cwd=tree, env=env)
    return tmp / "fmu"


def cpu_seconds_per_step(steps: Callable[[int], None]) -> float:
    t0 = time.process_time()
    steps(N_STEPS)
    return (time.process_time() - t0) / N_STEPS


def main() -> None:
    revision = sys.argv[1] if len(sys.argv) > 1 else "main"
    with tempfile.TemporaryDirectory(prefix="wmr-ab-") as tmp:
        dirs = {"this tree": build_fmus().fmus[2].parent, revision: build_at(revision, Path(tmp))}
        plants = {(side, v): FmuPlant(d / f"wmr_robot-fmi{v}.fmu")
                  for side, d in dirs.items() for v in (2, 3)}
        samples: dict[tuple[str, int, str], list[float]] = {}
        for _ in range(ROUNDS):
            for (side, v), plant in plants.items():
                plant.reset(RobotParams(), Pose(0, 0, 0))

                def raw(n: int, plant: FmuPlant = plant) -> None:
                    for k in range(n):
                        plant.step(1.0 if (k % 200) < 100 else -1.0, 0.8, H)

                samples.setdefault((side, v, "raw ctypes"), []).append(cpu_seconds_per_step(raw))
                plant.reset(RobotParams(), Pose(0, 0, 0))
                samples.setdefault((side, v, "fmpy's API"), []).append(
                    cpu_seconds_per_step(_fmpy_stepper(plant, v)))
        for plant in plants.values():
            plant.close()
    print(f"One {H * 1e3:.0f} ms co-simulation step, CPU time, median of {ROUNDS} x {N_STEPS}")
    print(f"{'what':<24}  {revision + ' us':>12}  {'this tree us':>12}  {'ratio':>6}")
    for v in (2, 3):
        for path in ("fmpy's API", "raw ctypes"):
            old = statistics.median(samples[(revision, v, path)])
            new = statistics.median(samples[("this tree", v, path)])
            print(f"{f'FMI {v} {path}':<24}  {old * 1e6:>12.3f}  {new * 1e6:>12.3f}  "
                  f"{new / old:>6.3f}")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    main()

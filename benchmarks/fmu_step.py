"""Cost of one 10 ms co-simulation step of the robot FMU, three ways, measured side by side.

1. through fmpy's own API (``setReal``/``doStep``/``getReal``, its checked wrappers),
2. raw ctypes calls into the same shared library: :meth:`wmr.adapters.fmi.robot.FmuPlant.step`,
whose    prebound calls check each status themselves,
3. the same physics and integrator in a pure C loop (the FMU's own sources, no FMI calls).

Run: ``python benchmarks/fmu_step.py``.  Prints medians and ratios to the pure C loop.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path

from _common import median_time_per_call, print_table
from wmr.adapters.fmi.robot import FmuPlant
from wmr.build.fmus import build_fmus
from wmr.core.plant import Pose, RobotParams

H = 0.01
N_STEPS = 2000

C_LOOP = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "model.h"
#include "solver.h"
#define STEP_H H_VALUE
int main(int argc, char **argv) {
    long n = argc > 1 ? atol(argv[1]) : 1000;
    double p[MODEL_NP], x[MODEL_NX], u[MODEL_NU] = {1.0, 0.8};
    for (int i = 1; i < MODEL_NV; i++)
        if (MODEL_VARIABLES[i].kind == MODEL_VAR_PARAMETER)
            p[MODEL_VARIABLES[i].index] = MODEL_VARIABLES[i].start;
    model_initial_state(p, x);
    SolverState s; solver_init(&s);
    char msg[256];
    struct timespec a, b;
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (long k = 0; k < n; k++) {
        u[0] = (k % 200) < 100 ? 1.0 : -1.0;
        if (solver_integrate(&s, k * STEP_H, (k + 1) * STEP_H, x, u, p, msg, sizeof msg)) {
            fprintf(stderr, "%s\n", msg); return 1;
        }
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%.9e\n", ((b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec)) / n);
    return 0;
}
"""


def c_loop_seconds(fmu: Path, n: int, repeats: int = 7) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        with zipfile.ZipFile(fmu) as zf:
            zf.extractall(tmp)
        src = Path(tmp) / "sources"
        (src / "bench_main.c").write_text(C_LOOP.replace("H_VALUE", repr(H)))
        exe = Path(tmp) / "bench"
        files = [src / f for f in ("bench_main.c", "solver.c", "model_generated.c",
                                   "model_variables.c")]
        subprocess.run(["gcc", "-O2", "-std=c99", f"-I{src}", *map(str, files), "-o", str(exe),
                        "-lm"], check=True)
        times = sorted(float(subprocess.run([str(exe), str(n)], check=True, capture_output=True,
                                            text=True).stdout) for _ in range(repeats))
        return times[len(times) // 2]


def _fmpy_stepper(plant: FmuPlant, version: int) -> Callable[[int], None]:
    """Steps through fmpy's own FMU2Slave/FMU3Slave API on the plant's instance."""
    fmu = plant._slave.fmu
    vr_in = [int(v) for v in plant._in_vr]
    vr_out = [int(v) for v in plant._out_vr]
    set_values = fmu.setReal if version == 2 else fmu.setFloat64
    get_values = fmu.getReal if version == 2 else fmu.getFloat64
    t_box = [plant.time_s]

    def steps(n: int) -> None:
        t0, h = t_box[0], H
        for k in range(n):
            set_values(vr_in, [1.0 if (k % 200) < 100 else -1.0, 0.8])
            fmu.doStep(t0 + k * h, h)
            get_values(vr_out)
        t_box[0] = t0 + n * h

    return steps


def main() -> None:
    fmus = build_fmus().fmus
    rows: list[tuple[str, float]] = []
    for version in (2, 3):
        plant = FmuPlant(fmus[version])
        plant.reset(RobotParams(), Pose(0, 0, 0))

        rows.append((f"FMI {version} through fmpy's API",
                     median_time_per_call(_fmpy_stepper(plant, version), N_STEPS)))
        plant.reset(RobotParams(), Pose(0, 0, 0))

        def raw_steps(n: int, plant: FmuPlant = plant) -> None:
            for k in range(n):
                plant.step(1.0 if (k % 200) < 100 else -1.0, 0.8, H)

        rows.append((f"FMI {version} raw ctypes (FmuPlant.step)",
                     median_time_per_call(raw_steps, N_STEPS)))
        plant.close()
    rows.append(("pure C loop (solver + model core)", c_loop_seconds(fmus[3], 20 * N_STEPS)))
    print_table(f"One {H * 1e3:.0f} ms co-simulation step of the robot FMU "
                f"(median of 7 x {N_STEPS} steps)", rows, "pure C loop (solver + model core)")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    main()

"""The closed loop's cost per control step against its C floor, measured side by side in one run.

The floor: ``loop_floor.c`` (compiled here with the system ``cc``) loads the robot FMU's and
the controller FMU's shared libraries and runs the Fig. 11 closed loop through their FMI 3
entry points, the stabiliser and wheel servos in C, no log.  Every row is the marginal cost of
one control step: two runs of the Fig. 11 case, to the goal (2672 steps) and stopped at
``max_time_s = SHORT_S``, timed whole (``run_to_log`` is ``wmr run`` minus the FMU load), so
that the start-up (instantiation, log header, fsync and rename) cancels:
``(t_long - t_short) / (steps_long - steps_short)``, in wall time and in CPU time (the
process's, every thread; on a machine shared with other jobs the CPU time is the steadier of the
two, and it is what a batch that keeps every core busy pays).  Each repetition runs every row
once, in turn (interleaved), and the table shows medians over ``REPEATS``.  Every row must stop
at the floor's step counts (the same closed loop), or the script stops.

Rows: the floor; the paper's PI compiled into the C stepper (``wmr run`` and ``wmr batch``
with the default controller, :mod:`wmr.adapters.fmi.compiled_law`: the Python law's bits)
logged and unlogged; the Python stabiliser (``SpecController``: what the default ran before,
and what every peer controller and every run with sensors runs) logged and unlogged; the
controller FMU (``--controller-fmu``) logged and unlogged; the last four with the C stepper
(:func:`wmr.adapters.stepper.load_stepper`) and without it (``WMR_STEPPER=0``, the
pure-Python path, which was the only one before the stepper).

Run: ``python benchmarks/loop_vs_c_floor.py``.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from time import perf_counter, process_time

from wmr.adapters.fmi.compiled_law import CompiledLawController
from wmr.adapters.fmi.controller import FmuController, controller_parameters
from wmr.adapters.fmi.robot import FmuPlant
from wmr.apps.run import run_to_log
from wmr.build.controller_interface import INPUTS, SIGNAL_OUTPUTS
from wmr.build.fmus import build_fmus
from wmr.config.scenario import load_scenario
from wmr.core.closedloop import run_closed_loop
from wmr.core.control.from_spec import SpecController
from wmr.core.plant import OUTPUT_NAMES
from wmr.core.runspec import RunSpec

REPEATS = 7
SHORT_S = 8.0  # the short run: Fig. 11 stopped at 8 s (801 steps)
FLOOR = "C floor (both FMUs from C, no log)"


def _library(fmu: Path, into: Path) -> tuple[str, str, dict[str, int]]:
    """Extract an FMI 3 FMU's Linux binary: its path, token and value references by name."""
    from fmpy import read_model_description

    md = read_model_description(str(fmu))
    ident = md.coSimulation.modelIdentifier
    with zipfile.ZipFile(fmu) as zf:
        zf.extract(f"binaries/x86_64-linux/{ident}.so", into)
    vrs = {v.name: v.valueReference for v in md.modelVariables}
    return str(into / "binaries" / "x86_64-linux" / f"{ident}.so"), md.guid, vrs


def _floor_input(spec: RunSpec, short: RunSpec, robot: Path, ctrl: Path, tmp: Path) -> str:
    r_lib, r_token, r_vr = _library(robot, tmp / "robot")
    c_lib, c_token, c_vr = _library(ctrl, tmp / "ctrl")
    rp = spec.params.as_dict() | {"x0": spec.start.x_m, "y0": spec.start.y_m,
                                  "theta0": spec.start.heading_rad, "v0": 0.0, "omega0": 0.0}
    cp = controller_parameters(spec)
    c_out = (*SIGNAL_OUTPUTS, "phase", "converged")
    lines = [f"{r_lib} {r_token} {c_lib} {c_token}",
             f"{spec.period_s!r} {spec.n_steps_max} {short.n_steps_max} 1",
             f"{len(rp)} " + " ".join(f"{r_vr[k]} {v!r}" for k, v in rp.items()),
             f"{len(cp)} " + " ".join(f"{c_vr[k]} {v!r}" for k, v in cp.items()),
             f"{r_vr['tau_r']} {r_vr['tau_l']}",
             f"{len(OUTPUT_NAMES)} " + " ".join(str(r_vr[n]) for n in OUTPUT_NAMES),
             f"{len(INPUTS)} " + " ".join(str(c_vr[n]) for n in INPUTS),
             f"{len(c_out)} " + " ".join(str(c_vr[n]) for n in c_out),
             f"{c_out.index('tau_r')} {c_out.index('tau_l')} {c_out.index('converged')}"]
    return "\n".join(lines) + "\n"


def _compile_floor(tmp: Path) -> Path:
    import fmpy

    cc = os.environ.get("CC") or shutil.which("cc") or "gcc"
    exe = tmp / "loop_floor"
    subprocess.run([cc, "-O2", "-std=c99", "-D_POSIX_C_SOURCE=199309L",
                    f"-I{Path(fmpy.__file__).parent / 'c-code'}",
                    str(Path(__file__).parent / "loop_floor.c"), "-o", str(exe), "-ldl"],
                   check=True)
    return exe


def main() -> None:
    spec = load_scenario("fig11").runs[0]
    short = dataclasses.replace(spec, t_max_s=SHORT_S)
    built = build_fmus()
    robot, ctrl_fmu = built.fmus[3], built.controllers[3]
    samples: dict[str, list[tuple[float, float]]] = {}  # (wall, CPU) s per step
    steps_seen: dict[str, tuple[int, int]] = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        exe = _compile_floor(tmp)
        floor_in = _floor_input(spec, short, robot, ctrl_fmu, tmp)
        plants, ctrls = {}, {}
        for mode in ("1", "0"):  # the stepper is bound when the instance is made
            os.environ["WMR_STEPPER"] = mode
            plants[mode] = FmuPlant(robot)
            plants[mode].reset(spec.params, spec.start)
            ctrls[mode] = FmuController(ctrl_fmu)
        os.environ.pop("WMR_STEPPER")
        log = tmp / "run.mcap"

        def python_rows(mode: str, tag: str) -> dict[str, Callable[[RunSpec], int]]:
            plant, cfmu = plants[mode], ctrls[mode]
            compiled = {
                "wmr run (the PI compiled into the stepper: the default), logged":
                    lambda s: int(run_to_log(s, log, plant)["steps"]),
                "the PI compiled into the stepper, no log":
                    lambda s: run_closed_loop(s, plant, controller=CompiledLawController()).steps,
            } if mode == "1" else {}
            return compiled | {
                f"wmr run, Python stabiliser, logged{tag}":
                    lambda s: int(run_to_log(s, log, plant, controller=SpecController())["steps"]),
                f"Python stabiliser, no log{tag}":
                    lambda s: run_closed_loop(s, plant, controller=SpecController()).steps,
                f"wmr run --controller-fmu, logged{tag}":
                    lambda s: int(run_to_log(s, log, plant, controller_fmu=cfmu)["steps"]),
                f"controller FMU, no log{tag}":
                    lambda s: run_closed_loop(s, plant, controller=cfmu).steps,
            }

        def without_stepper(fun: Callable[[RunSpec], int]) -> Callable[[RunSpec], int]:
            def run(s: RunSpec) -> int:  # the log writer's encoder too: numpy's
                os.environ["WMR_STEPPER"] = "0"
                try:
                    return fun(s)
                finally:
                    os.environ.pop("WMR_STEPPER")
            return run

        rows = python_rows("1", "") | {
            name: without_stepper(fun)
            for name, fun in python_rows("0", " (no stepper: before)").items()}
        for fun in rows.values():  # warm-up
            fun(short)
        for _ in range(REPEATS):
            proc = subprocess.run([str(exe)], input=floor_in, capture_output=True, text=True,
                                  check=True)
            n_l, w_l, c_l, n_s, w_s, c_s = proc.stdout.split()
            steps_seen[FLOOR] = (int(n_l), int(n_s))
            per_step = int(n_l) - int(n_s)
            samples.setdefault(FLOOR, []).append(
                ((float(w_l) - float(w_s)) / per_step, (float(c_l) - float(c_s)) / per_step))
            for name, fun in rows.items():
                w0, c0 = perf_counter(), process_time()
                n_long = fun(spec)
                w1, c1 = perf_counter(), process_time()
                n_short = fun(short)
                w2, c2 = perf_counter(), process_time()
                steps_seen[name] = (n_long, n_short)
                per_step = n_long - n_short
                samples.setdefault(name, []).append(
                    (((w1 - w0) - (w2 - w1)) / per_step, ((c1 - c0) - (c2 - c1)) / per_step))
        for plant in plants.values():
            plant.close()
        for cfmu in ctrls.values():
            cfmu.close()
    wall_floor = statistics.median(w for w, _ in samples[FLOOR])
    cpu_floor = statistics.median(c for _, c in samples[FLOOR])
    width = max(len(n) for n in samples)
    print(f"Closed loop, Fig. 11 case: marginal cost of one control step "
          f"(runs of {steps_seen[FLOOR][0]} and {steps_seen[FLOOR][1]} steps), "
          f"median of {REPEATS} interleaved repetitions")
    print(f"{'path':<{width}}  {'wall us':>8}  {'x floor':>7}  {'CPU us':>8}  {'x floor':>7}")
    for name, values in samples.items():
        wall = statistics.median(w for w, _ in values)
        cpu = statistics.median(c for _, c in values)
        if steps_seen[name] != steps_seen[FLOOR]:
            raise SystemExit(f"{name}: {steps_seen[name]} steps, the floor "
                             f"{steps_seen[FLOOR]}: not the same closed loop")
        print(f"{name:<{width}}  {wall * 1e6:>8.3f}  {wall / wall_floor:>7.2f}  "
              f"{cpu * 1e6:>8.3f}  {cpu / cpu_floor:>7.2f}")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    main()

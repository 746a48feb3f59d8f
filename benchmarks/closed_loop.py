"""Cost per 10 ms control step of the closed loop, split into its parts, measured in one run.

Rows (median of repeated runs of the paper's Fig. 11 case on the FMI 3 FMU):

- FMU exchange: ``FmuPlant.step`` alone (set inputs, doStep, get outputs: one call into the C
  stepper when it is built, three ctypes calls without it),
- controller: the stabiliser and wheel servos alone, on the states of a recorded run,
- controller FMU: the same law in C (``FmuController``: set inputs, get outputs, doStep through
  ctypes, with the convergence test the master asks first), on the same states,
- loop with the controller FMU: ``run_closed_loop(..., controller=FmuController(...))``,
- loop without logging: ``run_closed_loop(..., sink=None, controller=SpecController())``,
- loop with logging: ``run_to_log`` (the whole ``wmr run`` minus start-up),
- logging: the time spent inside the log writer during that run (``write_block`` and
  ``close``, timed directly: the difference of two noisy totals is noisier still).

The loops against their C floor, side by side: ``python benchmarks/loop_vs_c_floor.py``.

Run: ``python benchmarks/closed_loop.py``.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from _common import print_table
from wmr.adapters.fmi.controller import FmuController
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import RunLogWriter, read_run
from wmr.apps.run import run_to_log
from wmr.build.fmus import build_fmus
from wmr.config.scenario import load_scenario
from wmr.core.closedloop import run_closed_loop
from wmr.core.control import PIController
from wmr.core.control.from_spec import SpecController

REPEATS = 7


def _median(samples: list[float]) -> float:
    return statistics.median(samples)


def main() -> None:
    spec = load_scenario("fig11").runs[0]
    built = build_fmus()
    fmu = built.fmus[3]
    with FmuPlant(fmu) as plant, FmuController(built.controllers[3]) as cfmu, \
            tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "run.mcap"
        run_to_log(spec, log, plant)  # warm-up, and a recorded run for the controller row
        data = read_run(log)
        steps = data.n_steps
        s = data.signals
        states = list(zip(s["x_m"], s["y_m"], s["theta_rad"], s["omega_r_radps"],
                          s["omega_l_radps"], strict=True))
        speeds = list(zip(s["v_mps"], s["omega_radps"], strict=True))
        tol = spec.heading_tolerance_rad
        torques = list(zip(s["tau_r_nm"], s["tau_l_nm"], strict=True))

        fmu_t, ctrl_t, loop_t, logged_t, log_t = [], [], [], [], []
        cfmu_t, cloop_t = [], []
        in_writer = [0.0]
        write_block, close = RunLogWriter.write_block, RunLogWriter.close

        def timed(fun: Callable[..., None]) -> Callable[..., None]:
            def wrapper(*args: object) -> None:
                t = time.perf_counter()
                fun(*args)
                in_writer[0] += time.perf_counter() - t
            return wrapper

        RunLogWriter.write_block = timed(write_block)  # type: ignore[method-assign]
        RunLogWriter.close = timed(close)  # type: ignore[method-assign]
        for _ in range(REPEATS):
            plant.reset(spec.params, spec.start)
            t0 = time.perf_counter()
            for tr, tl in torques:
                plant.step(tr, tl, spec.period_s)
            fmu_t.append((time.perf_counter() - t0) / steps)

            ctrl = PIController(spec.goal, spec.gains, spec.limits, spec.params, spec.period_s,
                              spec.stop_radius_m)
            t0 = time.perf_counter()
            for x, y, th, wr, wl in states:
                ctrl.step(x, y, th, wr, wl)
            ctrl_t.append((time.perf_counter() - t0) / steps)

            cfmu.configure(spec)
            converged = cfmu.stabiliser.converged
            t0 = time.perf_counter()
            for (x, y, th, wr, wl), (v, om) in zip(states, speeds, strict=True):
                converged(x, y, th, v, om, tol)
                cfmu.step(x, y, th, wr, wl)
            cfmu_t.append((time.perf_counter() - t0) / steps)

            t0 = time.perf_counter()
            result = run_closed_loop(spec, plant, controller=cfmu)
            cloop_t.append((time.perf_counter() - t0) / result.steps)

            t0 = time.perf_counter()
            result = run_closed_loop(spec, plant, controller=SpecController())
            loop_t.append((time.perf_counter() - t0) / result.steps)

            in_writer[0] = 0.0
            t0 = time.perf_counter()
            record = run_to_log(spec, log, plant)
            logged_t.append((time.perf_counter() - t0) / int(record["steps"]))
            log_t.append(in_writer[0] / int(record["steps"]))

    fmu_s, ctrl_s, loop_s, logged_s, log_s, cfmu_s, cloop_s = map(
        _median, (fmu_t, ctrl_t, loop_t, logged_t, log_t, cfmu_t, cloop_t))
    rows = [
        ("FMU exchange (FmuPlant.step)", fmu_s),
        ("controller (stabiliser + wheel servos)", ctrl_s),
        ("controller FMU (same law in C, ctypes)", cfmu_s),
        ("loop without logging", loop_s),
        ("loop without logging, controller FMU", cloop_s),
        ("loop with MCAP logging (wmr run)", logged_s),
        ("logging (inside the MCAP writer)", log_s),
        ("loop bookkeeping (loop - FMU - controller)", max(loop_s - fmu_s - ctrl_s, 0.0)),
    ]
    print_table(f"Closed loop, Fig. 11 case, {steps} steps of {spec.period_s * 1e3:.0f} ms "
                f"(median of {REPEATS})", rows, "FMU exchange (FmuPlant.step)")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    main()

"""Cost per 10 ms control step of the closed loop with sensors, against perfect feedback.

Rows (median of repeated runs of the paper's Fig. 11 case on the FMI 3 FMU, no logging):

- perfect state feedback (no ``[sensors]``),
- raw fixes (``wmr run --sensors raw``: GPS, compass, encoders, estimator ``none``),
- EKF (``wmr run --sensors gps``: the same sensors, the filter with its latency re-runs),
- sensing alone: ``Sensing.step`` with the EKF on the states of a recorded run.

Run: ``python benchmarks/sensing.py``.
"""

from __future__ import annotations

import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

from _common import print_table
from wmr.adapters.fmi.robot import FmuPlant
from wmr.build.fmus import build_fmus
from wmr.config.scenario import load_scenario
from wmr.core.closedloop import run_closed_loop
from wmr.core.control.from_spec import SpecController
from wmr.core.sensing import Sensing, preset

REPEATS = 5


def main() -> None:
    spec = replace(load_scenario("fig11").runs[0], t_max_s=20.0)  # no early stop: same steps
    fmu = build_fmus().fmus[3]
    variants = {"perfect state feedback": None, "raw fixes (--sensors raw)": preset("raw"),
                "EKF (--sensors gps)": preset("gps")}
    times: dict[str, list[float]] = {k: [] for k in variants}
    sensing_t: list[float] = []
    with FmuPlant(fmu) as plant:
        recorded = run_closed_loop(replace(spec, sensors=preset("gps")), plant,
                                   controller=SpecController())  # warm-up
        outputs = []
        plant.reset(spec.params, spec.start)
        for _ in range(recorded.steps):
            outputs.append(plant.step(1.0, 0.9, spec.period_s).copy())
        for _ in range(REPEATS):
            for name, sensors in variants.items():
                t0 = time.perf_counter()
                res = run_closed_loop(replace(spec, sensors=sensors), plant,
                                      controller=SpecController())
                times[name].append((time.perf_counter() - t0) / res.steps)
            sensing = Sensing(preset("gps"), spec.period_s, spec.params, spec.start, spec.goal)
            t0 = time.perf_counter()
            for n, out in enumerate(outputs):
                sensing.step(n, out)
            sensing_t.append((time.perf_counter() - t0) / len(outputs))
    rows = [(name, statistics.median(t)) for name, t in times.items()]
    rows.append(("Sensing.step alone (EKF)", statistics.median(sensing_t)))
    print_table(f"Closed loop with sensors, Fig. 11 case, {recorded.steps} steps of "
                f"{spec.period_s * 1e3:.0f} ms (median of {REPEATS})", rows,
                "perfect state feedback")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    main()

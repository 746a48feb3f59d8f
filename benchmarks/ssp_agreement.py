"""Agreement of SSP masters we did not write with ``wmr run``: master x FMI x scenario.

For every run of the given scenarios (default: fig11 fig9 fig10) the closed loop is exported
(``wmr ssp export``, FMI 2.0 and 3.0), run in libcosim (``wmr ssp run``'s engine) and in
fmpy's ``simulate_ssp``, and compared with ``wmr run`` at every control step
(:mod:`wmr.adapters.ssp.agreement`): the worst distance in mm and heading difference in degrees,
after the master's measured lag in steps.  FMI 3.0 packages are validated against the SSP 1.0 XSDs;
neither master here runs FMI 3.0 (the row says why).

Run: ``python benchmarks/ssp_agreement.py [SCENARIO ...]``.  Prints a Markdown table.
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

from wmr.adapters.ssp.agreement import (
    deviation,
    fmpy_path,
    libcosim_path,
    measured_lag,
    wmr_run_path,
)
from wmr.adapters.ssp.export import export_ssp
from wmr.build.fmus import build_fmus
from wmr.config.scenario import load_scenario


def main(scenarios: list[str]) -> None:
    from fmpy.ssp.ssd import read_ssd

    built = build_fmus()
    print("| master | FMI | run | lag (steps) | worst distance (mm) | worst heading (deg) "
          "| converged |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in scenarios:
            for spec in load_scenario(scenario).runs:
                _, ref = wmr_run_path(spec, built.fmus[2])
                ssp = {v: Path(tmp) / f"{spec.name}-fmi{v}.ssp" for v in (2, 3)}
                for v, path in ssp.items():
                    export_ssp(spec, path, built.fmus[v], built.controllers[v])
                    read_ssd(str(path), validate=True)
                rows = [("libcosim", *libcosim_path(ssp[2]))]
                conv, fpath = fmpy_path(ssp[2], len(ref) * spec.period_s + 0.1)
                rows.append(("fmpy simulate_ssp", "converged" if conv else "no", fpath))
                for master, state, xy_theta in rows:
                    lag = measured_lag(xy_theta, ref)
                    pos, head = deviation(xy_theta, ref, lag)
                    print(f"| {master} | 2.0 | {spec.name} | {lag} | {pos * 1e3:.2f} "
                          f"| {math.degrees(head):.3f} | {state} |", flush=True)
                print(f"| libcosim, fmpy | 3.0 | {spec.name} | - | - | - | package valid; "
                      "neither master loads FMI 3.0 |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["fig11", "fig9", "fig10"])

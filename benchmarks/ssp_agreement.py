"""Agreement of SSP masters we did not write with ``wmr run``: master x FMI x scenario.

For every run of the given scenarios (default: fig11 fig9 fig10) the closed loop is exported
(``wmr ssp export``, FMI 2.0 and 3.0), run in libcosim and Ecos (``wmr ssp run``'s engines;
Ecos on both FMI versions) and in fmpy's ``simulate_ssp``, and compared with ``wmr run`` at
every control step (:mod:`wmr.adapters.ssp.agreement`): the worst distance in mm and heading
difference in degrees, after the master's measured lag in steps, and the rows to convergence
minus ``wmr run``'s.  Both packages are validated against the SSP 1.0 XSDs.

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
from wmr.adapters.ssp.ecos import simulate_ecos
from wmr.adapters.ssp.export import export_ssp
from wmr.build.fmus import build_fmus
from wmr.config.scenario import load_scenario


def main(scenarios: list[str]) -> None:
    from fmpy.ssp.ssd import read_ssd

    built = build_fmus()
    print("| master | FMI | run | lag (steps) | worst distance (mm) | worst heading (deg) "
          "| converged | steps - wmr run's |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in scenarios:
            for spec in load_scenario(scenario).runs:
                _, ref = wmr_run_path(spec, built.fmus[2])
                ssp = {v: Path(tmp) / f"{spec.name}-fmi{v}.ssp" for v in (2, 3)}
                for v, path in ssp.items():
                    export_ssp(spec, path, built.fmus[v], built.controllers[v])
                    read_ssd(str(path), validate=True)
                rows = [("libcosim", "2.0", *libcosim_path(ssp[2]))]
                for v in (2, 3):
                    run = simulate_ecos(ssp[v])
                    rows.append(("ecos", f"{v}.0", run.status, run.block[:, :3]))
                conv, fpath = fmpy_path(ssp[2], len(ref) * spec.period_s + 0.1)
                rows.append(("fmpy simulate_ssp", "2.0", "converged" if conv else "no", fpath))
                for master, fmi, state, xy_theta in rows:
                    lag = measured_lag(xy_theta, ref)
                    pos, head = deviation(xy_theta, ref, lag)
                    extra = len(xy_theta) - lag - len(ref)
                    print(f"| {master} | {fmi} | {spec.name} | {lag} | {pos * 1e3:.2f} "
                          f"| {math.degrees(head):.3f} | {state} | {extra:+d} |", flush=True)

if __name__ == "__main__":
    main(sys.argv[1:] or ["fig11", "fig9", "fig10"])

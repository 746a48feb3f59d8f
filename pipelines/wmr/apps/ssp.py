"""``wmr ssp export`` and ``wmr ssp run``: a scenario's closed loop as an SSP 1.0 package, and a
package run in libcosim or Ecos, logged to MCAP like ``wmr run`` (``wmr ssp check``:
:mod:`wmr.apps.ssp_check`).

Errors name the inputs by these functions' keywords (``out``, ``run``, ``stop_time_s``); the
command line names them by its options.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from wmr.infra.errors import ConfigError


def export_package(scenario: str | Path | None = None, *, run: str | None = None,
                   start: Sequence[float] | None = None, goal: Sequence[float] | None = None,
                   fmi: int = 2, robot_fmu: str | Path | None = None,
                   controller_fmu: str | Path | None = None,
                   fmu_map: str | Path | None = None,
                   out: str | Path | None = None,
                   steps_per_period: int | None = None) -> Path:
    """Write the run ``run`` of ``scenario`` (``start`` and ``goal`` ``(x_m, y_m,
    heading_deg)`` over it) as an SSP package of the robot FMU (default: the scenario's, else
    the build for ``fmi``) and the controller FMU (default: the build) to ``out`` (default
    ``ssp/NAME.ssp``, NAME the run's as ``wmr run`` names it), its masters stepped at the
    control period / ``steps_per_period`` (default
    :data:`~wmr.adapters.ssp.export.DEFAULT_STEPS_PER_PERIOD`); return the package's path."""
    from dataclasses import replace

    from wmr.adapters.fmi.varmap import load_map
    from wmr.adapters.ssp.export import export_ssp
    from wmr.apps.run import select_run
    from wmr.build.fmus import build_fmus
    from wmr.config.naming import default_log_path, fmu_tokens, run_name, variant_name
    from wmr.config.scenario import Overrides, load_scenario, with_overrides
    from wmr.infra.outputs import check_output

    sc = load_scenario(scenario)
    base = select_run(sc, run)
    spec = with_overrides(base, Overrides(start=start, goal=goal))
    # the scenario file is the provenance of its own run only: a variant's package carries
    # its effective scenario instead (export_ssp), as a variant's log of 'wmr run' does
    scenario_file = sc.path if spec == base else None
    # named as wmr run names a variant: the run (SSD, parameter sets) after what it changes,
    # the file also after the FMI version, so that another goal or FMI version never
    # overwrites the scenario's own package nor passes for it
    spec = replace(spec, name=run_name(base, spec))
    name = variant_name(spec.name, fmu_tokens(fmi, None if robot_fmu is None
                                              else str(robot_fmu), 2))
    path = check_output(out if out else default_log_path(name, "ssp", ".ssp"), "out",
                        suffix=".ssp")
    built = None
    robot_choice = robot_fmu or sc.fmu
    if robot_choice is None or controller_fmu is None:
        built = build_fmus()
    robot = Path(robot_choice) if robot_choice else built.fmus[fmi]  # type: ignore[union-attr]
    map_path = Path(fmu_map) if fmu_map else sc.fmu_map
    ctrl = (Path(controller_fmu) if controller_fmu
            else built.controllers[fmi])  # type: ignore[union-attr]
    return export_ssp(spec, path, robot, ctrl, scenario_file=scenario_file,
                      var_map=load_map(map_path) if map_path is not None else None,
                      **({} if steps_per_period is None
                         else {"steps_per_period": steps_per_period}))


def run_package(ssp: str | Path, *, out: str | Path | None = None,
                stop_time_s: float | None = None, master: str = "auto") -> dict[str, Any]:
    """Run the package ``ssp`` in ``master`` (``libcosim``, ``ecos``, or ``auto``: libcosim
    for an FMI 2.0 package, Ecos for 3.0) to ``stop_time_s`` (default the package's) and log
    it to ``out`` (default ``runs/NAME-ssp.mcap``); return the run's record."""
    from wmr.adapters.ssp.cosim import log_ssp_run, simulate_libcosim
    from wmr.config.naming import default_log_path
    from wmr.core.runspec import DEFAULT_PERIOD_S, MAX_STEPS
    from wmr.infra.outputs import check_output

    ssp = Path(ssp)
    # '-ssp': the package of fig11 must not overwrite runs/fig11.mcap of 'wmr run fig11'
    path = check_output(out if out else default_log_path(f"{ssp.stem}-ssp"), "out",
                        suffix=".mcap")
    # the longest run a scenario allows at the default period: libcosim sizes its buffers by it
    longest_s = MAX_STEPS * DEFAULT_PERIOD_S
    if stop_time_s is not None and not 0 < stop_time_s <= longest_s:
        raise ConfigError("stop_time_s", f"must be > 0 and at most {longest_s:g} s, got "
                          f"{stop_time_s:g}", "give seconds, e.g. stop_time_s=30")
    if master == "auto":  # libcosim loads FMI 2.0 only
        from wmr.adapters.ssp.package import ROBOT, read_package

        fmi3 = read_package(ssp).component(ROBOT).fmi_version.startswith("3")
        master = "ecos" if fmi3 else "libcosim"
    if master == "ecos":
        from wmr.adapters.ssp.ecos import simulate_ecos

        run = simulate_ecos(ssp, stop_time_s=stop_time_s)
    else:
        run = simulate_libcosim(ssp, stop_time_s=stop_time_s)
    return log_ssp_run(run, path)


__all__ = ["export_package", "run_package"]

"""``wmr ssp check PKG``: one SSP package in every master installed here, against ``wmr run``.

Each master runs the package as its user would (:data:`MASTERS`): libcosim and Ecos as ``wmr
ssp run`` does (to the controller's ``converged`` sample), fmpy's ``simulate_ssp`` with the
package's own parameter sets to the package's stop time (it cannot stop earlier), OMSimulator
when its Python package is importable.  The reference is ``wmr run`` of the package's own
scenario (its provenance ``resources/NAME.toml``, the run named as the package) on the
package's own robot FMU, through the package's variable map for a robot FMU of another tool:
the names of the robot are only ever the map's.

A row per master: its FMI version, when it converged, its final pose's distance from ``wmr
run``'s, its path's worst distance from ``wmr run``'s after its measured lag
(:mod:`wmr.adapters.ssp.agreement`), and what it said.  A master that cannot load the package
(an FMI version it does not take, not installed) is a row saying so and is not counted; one
that fails is a row with its error, and counts as not agreeing.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from wmr.adapters.ssp.agreement import (
    HEADING_BAR_RAD,
    POSITION_BAR_M,
    deviation,
    fmpy_run,
    measured_lag,
    wmr_run,
)
from wmr.adapters.ssp.cosim import simulate_libcosim
from wmr.adapters.ssp.ecos import simulate_ecos
from wmr.adapters.ssp.export import MAP_NAME
from wmr.adapters.ssp.omsimulator import converged_at_s, omsimulator, simulate_omsimulator
from wmr.adapters.ssp.package import ROBOT, SspPackage, unpacked_package
from wmr.config.scenario import parse_scenario
from wmr.core.runspec import RunSpec
from wmr.core.signals import COLUMN
from wmr.infra.errors import ConfigError

_POSE: Final = [COLUMN["x_m"], COLUMN["y_m"], COLUMN["theta_rad"]]
#: A master's path is compared at up to this many steps of lag (fmpy: 1, docs/ssp.md).
MAX_LAG_STEPS: Final = 2


class NotLoaded(Exception):
    """The master cannot take this package (an FMI version it does not load, a feature it
    ignores, not installed): a row that says why, not counted in the verdict."""


@dataclass(frozen=True)
class MasterRun:
    """What a master returned: its name and version, when its ``converged`` output first rose
    (``None``: never), and the robot's ``(x, y, theta)`` at ``t_0, t_1, ...`` in our units."""

    master: str
    converged_at_s: float | None
    path: npt.NDArray[np.float64]
    #: What the master's row says after "ok" (how the package was given to it), or nothing.
    note: str = ""


#: A master's runner: the package file and the package read back -> its run.
Runner = Callable[[Path, SspPackage], MasterRun]


def _fmi(package: SspPackage) -> str:
    return package.component(ROBOT).fmi_version


def _run_libcosim(ssp: Path, package: SspPackage) -> MasterRun:
    if not _fmi(package).startswith("2"):
        raise NotLoaded(f"cannot load it: libcosimpy loads FMI 2.0 FMUs only, this package is "
                        f"FMI {_fmi(package)}")
    try:
        import libcosimpy  # noqa: F401
    except ImportError:
        raise NotLoaded("not installed (pip install 'wmr-cosim[ssp]')") from None
    run = simulate_libcosim(ssp)
    return MasterRun(run.master, run.time_to_goal_s, run.block[:, _POSE])


def _run_ecos(ssp: Path, package: SspPackage) -> MasterRun:
    try:
        import ecospy  # noqa: F401
    except ImportError:
        raise NotLoaded("not installed (pip install 'wmr-cosim[ssp]')") from None
    except OSError:
        pass  # a library that does not load: simulate_ecos says which, as a failed row
    run = simulate_ecos(ssp)
    return MasterRun(run.master, run.time_to_goal_s, run.block[:, _POSE])


def _run_fmpy(ssp: Path, package: SspPackage) -> MasterRun:
    from importlib.metadata import version

    if _fmi(package)[:1] not in ("1", "2"):
        raise NotLoaded(f"cannot load it: simulate_ssp loads FMI 1.0 and 2.0 FMUs only, this "
                        f"package is FMI {_fmi(package)}")
    if package.robot_map is not None:
        # simulate_ssp passes connections without their ssc:LinearTransformation, and names
        # the robot's outputs in the other tool's names (docs/ssp.md)
        raise NotLoaded("not run: simulate_ssp ignores the package's unit transformations "
                        "(a robot FMU of another tool)")
    if package.stop_time_s is None:
        raise NotLoaded("not run: the package has no stop time")
    converged_at_s, path = fmpy_run(ssp, package.stop_time_s)
    return MasterRun(f"fmpy {version('fmpy')}", converged_at_s, path)


def _run_omsimulator(ssp: Path, package: SspPackage) -> MasterRun:
    try:
        omsimulator()
    except ConfigError as exc:
        raise NotLoaded(f"OMSimulator {exc.problem} (docs/ssp.md, 'OMSimulator')") from None
    if package.robot_map is not None:
        # no ssc:LinearTransformation in its source at 3.0.0.post103: the other tool's units
        # reach the controller unconverted (measured: 1.1 m off, never converged)
        raise NotLoaded("not run: OMSimulator ignores the package's unit transformations (a "
                        "robot FMU of another tool)")
    run = simulate_omsimulator(ssp)
    name = run.extra["model_name"]
    note = "" if name == package.name else \
        f"its model named {name}: it takes identifiers only (docs/ssp.md, 'OMSimulator')"
    return MasterRun(run.master, converged_at_s(run), run.block[:, _POSE], note)


#: The masters, in the order of the table.  Tests replace one to make it fail.
MASTERS: dict[str, Runner] = {
    "libcosim": _run_libcosim,
    "ecos": _run_ecos,
    "fmpy": _run_fmpy,
    "omsimulator": _run_omsimulator,
}


@dataclass(frozen=True)
class CheckRow:
    """One master's row of ``wmr ssp check`` (distances in mm, angles in degrees; ``None``
    where the master did not run)."""

    master: str
    fmi_version: str
    ran: bool
    converged_at_s: float | None
    final_distance_mm: float | None
    final_heading_deg: float | None
    worst_distance_mm: float | None
    worst_heading_deg: float | None
    lag_steps: int | None
    said: str
    #: Within the bars and converged as ``wmr run`` did; ``None``: not run, not counted.
    agrees: bool | None


@dataclass(frozen=True)
class CheckReport:
    """The whole check: the package, ``wmr run``'s row and one row per master."""

    package: str
    name: str
    fmi_version: str
    reference: CheckRow
    rows: tuple[CheckRow, ...]
    position_bar_mm: float
    heading_bar_deg: float

    @property
    def agrees(self) -> bool:
        """Every master that ran agrees, and at least one ran."""
        ran = [r for r in self.rows if r.agrees is not None]
        return bool(ran) and all(r.agrees for r in ran)

    def verdict(self) -> str:
        """One line: which masters agree, which do not, which did not run."""
        ok = [r.master.split()[0] for r in self.rows if r.agrees]
        bad = [f"{r.master.split()[0]} ({self._why(r)})" for r in self.rows
               if r.agrees is False]
        skipped = [r.master.split()[0] for r in self.rows if r.agrees is None]
        bars = f"{self.position_bar_mm:g} mm and {self.heading_bar_deg:g} deg"
        parts = [f"within {bars} of wmr run: {', '.join(ok) or 'none'}"]
        if bad:
            parts.append(f"NOT within: {', '.join(bad)}")
        if skipped:
            parts.append(f"not run: {', '.join(skipped)}")
        if not ok and not bad:
            parts.append("no master ran")
        return "; ".join(parts)

    def _why(self, row: CheckRow) -> str:
        """Why ``row`` does not agree, in a few words."""
        if not row.ran:
            return "failed"
        why = []
        if row.worst_distance_mm is not None and row.worst_distance_mm > self.position_bar_mm:
            why.append(f"worst distance {row.worst_distance_mm:.2f} mm")
        if row.worst_heading_deg is not None and row.worst_heading_deg > self.heading_bar_deg:
            why.append(f"worst heading {row.worst_heading_deg:.3f} deg")
        if (row.converged_at_s is None) != (self.reference.converged_at_s is None):
            why.append("converged" if row.converged_at_s is not None else "did not converge")
        return ", ".join(why)

    def as_dict(self) -> dict[str, object]:
        return {"package": self.package, "name": self.name, "fmi_version": self.fmi_version,
                "position_bar_mm": self.position_bar_mm,
                "heading_bar_deg": self.heading_bar_deg, "agrees": self.agrees,
                "reference": asdict(self.reference), "rows": [asdict(r) for r in self.rows]}


def package_run(package: SspPackage) -> RunSpec:
    """The package's own run: its provenance scenario (the one ``.toml`` member besides the
    variable map), the run named as the package (or its only run).

    Raises
    ------
    ConfigError
        The package carries no provenance scenario, or one without that run.
    """
    where = f"{package.path}"
    tomls = {n: data for n, (_, data) in package.attachments.items()
             if n.endswith(".toml") and n != Path(MAP_NAME).name}
    if len(tomls) != 1:
        raise ConfigError("SSP", f"{where} carries {len(tomls)} scenario files "
                          f"({', '.join(sorted(tomls)) or 'none'}), not its one provenance "
                          "resources/NAME.toml", "export it again with 'wmr ssp export'")
    (member, data), = tomls.items()
    source = f"{where}: resources/{member}"
    try:
        scenario = parse_scenario(tomllib.loads(data.decode()), source=source)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError("SSP", f"{source} is not a scenario file: {exc}",
                          "export it again with 'wmr ssp export'") from None
    runs = [r for r in scenario.runs if r.name == package.name]
    if not runs and len(scenario.runs) == 1:
        runs = list(scenario.runs)
    if not runs:
        raise ConfigError("SSP", f"{source} has no run named {package.name!r} (the "
                          "package's)", "export it again with 'wmr ssp export'")
    return runs[0]


def _compare(master: str, fmi: str, run: MasterRun, ref: npt.NDArray[np.float64],
             ref_converged: bool) -> CheckRow:
    lag = measured_lag(run.path, ref, MAX_LAG_STEPS)
    worst_m, worst_rad = deviation(run.path, ref, lag)
    end, ref_end = run.path[-1], ref[-1]
    final_m = math.hypot(end[0] - ref_end[0], end[1] - ref_end[1])
    final_rad = abs(end[2] - ref_end[2])
    converged = run.converged_at_s is not None
    within = worst_m <= POSITION_BAR_M and worst_rad <= HEADING_BAR_RAD
    said = "ok" if converged else "ok, but its controller never reported converged"
    if run.note:
        said = f"{said}; {run.note}"
    return CheckRow(master=master, fmi_version=fmi, ran=True,
                    converged_at_s=run.converged_at_s, final_distance_mm=final_m * 1e3,
                    final_heading_deg=math.degrees(final_rad), worst_distance_mm=worst_m * 1e3,
                    worst_heading_deg=math.degrees(worst_rad), lag_steps=lag, said=said,
                    agrees=within and converged == ref_converged)


def _row(key: str, runner: Runner, ssp: Path, package: SspPackage,
         ref: npt.NDArray[np.float64], ref_converged: bool) -> CheckRow:
    fmi = _fmi(package)
    try:
        run = runner(ssp, package)
    except NotLoaded as exc:
        return CheckRow(key, fmi, False, None, None, None, None, None, None, str(exc), None)
    except Exception as exc:  # any master's failure is its row, not our crash
        line = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        return CheckRow(key, fmi, False, None, None, None, None, None, None,
                        f"failed: {line}", False)
    return _compare(f"{key} ({run.master})", fmi, run, ref, ref_converged)


def check_package(ssp_path: str | os.PathLike[str]) -> CheckReport:
    """Run the package in every master of :data:`MASTERS` and ``wmr run`` of its own run.

    Raises
    ------
    ConfigError, FmuError
        The package is missing, refused, incomplete, or carries no provenance scenario.
    """
    ssp = Path(ssp_path)
    with unpacked_package(ssp) as (package, folder):
        spec = package_run(package)
        robot_fmu = folder / package.component(ROBOT).source
        result, ref = wmr_run(spec, robot_fmu, package.robot_map)
    ref_converged = result.status == "converged"
    fmi = _fmi(package)
    reference = CheckRow(master="wmr run", fmi_version=fmi, ran=True,
                         converged_at_s=result.time_to_goal_s, final_distance_mm=0.0,
                         final_heading_deg=0.0, worst_distance_mm=0.0, worst_heading_deg=0.0,
                         lag_steps=0, said=result.message, agrees=None)
    rows = tuple(_row(key, runner, ssp, package, ref, ref_converged)
                 for key, runner in MASTERS.items())
    return CheckReport(package=str(ssp), name=package.name, fmi_version=fmi,
                       reference=reference, rows=rows,
                       position_bar_mm=POSITION_BAR_M * 1e3,
                       heading_bar_deg=math.degrees(HEADING_BAR_RAD))


def _cell(value: float | int | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def format_table(report: CheckReport) -> str:
    """The report as a text table and the verdict line."""
    head = ("master", "FMI", "converged at (s)", "final pose (mm, deg)",
            "worst path (mm, deg)", "lag", "said")
    lines = [head]
    for r in (report.reference, *report.rows):
        final = "-" if r.final_distance_mm is None else \
            f"{r.final_distance_mm:.2f}, {r.final_heading_deg:.3f}"
        worst = "-" if r.worst_distance_mm is None else \
            f"{r.worst_distance_mm:.2f}, {r.worst_heading_deg:.3f}"
        lines.append((r.master, r.fmi_version, _cell(r.converged_at_s, ".2f"), final, worst,
                      _cell(r.lag_steps, "d"), r.said))
    widths = [max(len(line[i]) for line in lines) for i in range(len(head) - 1)]
    text = ["  ".join([*(c.ljust(w) for c, w in zip(line[:-1], widths, strict=True)),
                       line[-1]]).rstrip() for line in lines]
    return "\n".join([f"{report.package} ({report.name}, FMI {report.fmi_version}) against "
                      "wmr run of its own scenario:", *text, report.verdict()])


__all__ = ["MASTERS", "CheckReport", "CheckRow", "MasterRun", "NotLoaded", "check_package",
           "format_table", "package_run"]

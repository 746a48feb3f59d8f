"""OMSimulator (OpenModelica) as a master of ``wmr ssp export``'s package, in ``wmr ssp check``.

OMSimulator is not installable from the package registries: these tests run where its Python
package (``OMSimulator``, built from source, docs/ssp.md "OMSimulator") is on ``PYTHONPATH``
and skip with the reason elsewhere, but for the row of a machine without it.

The independent fact: OMSimulator's fixed-step master passes the robot's outputs to the
controller and the controller's outputs (direct feedthrough) to the robot in the order of its
dependency graph, so the robot holds ``g(z_k, y_k)`` over each step, the torque ``wmr run``
gives it: its path is ``wmr run``'s to the digits of its CSV result (``%.12g``).
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from wmr.adapters.ssp.agreement import deviation, wmr_run
from wmr.adapters.ssp.export import export_ssp
from wmr.adapters.ssp.package import ROBOT, unpacked_package
from wmr.build.fmus import BuildResult
from wmr.config.scenario import Overrides, load_scenario, with_overrides
from wmr.core.plant import Pose
from wmr.core.runspec import RunSpec
from wmr.infra.errors import ConfigError


def _omsimulator_or_skip() -> str:
    """OMSimulator's version, or skip the test saying why it is not importable."""
    from wmr.adapters.ssp.omsimulator import omsimulator_version

    try:
        return omsimulator_version()
    except ConfigError as exc:
        pytest.skip(f"OMSimulator {exc.problem}")


_NEAR_GOAL = Pose(1.0, 0.5, math.radians(30.0))


def _spec(start: Pose | None = None, goal: Pose = _NEAR_GOAL, t_max_s: float = 12.0
          ) -> RunSpec:
    """Fig. 11's robot and gains to a near goal (about 6 s), stopped at ``t_max_s``."""
    spec = next(iter(load_scenario("fig11").runs))
    return replace(with_overrides(spec, Overrides(start=start, goal=goal, max_time_s=t_max_s)),
                   name="oms")


def _package(built: BuildResult, spec: RunSpec, folder: Path, fmi: int = 2) -> Path:
    out = folder / f"{spec.name}-fmi{fmi}.ssp"
    export_ssp(spec, out, built.fmus[fmi], built.controllers[fmi])
    return out


@pytest.mark.parametrize("fmi", [2, 3])
@pytest.mark.parametrize("start", [None, Pose(0.5, -0.3, math.radians(170.0))],
                         ids=["origin", "variant"])
def test_omsimulator_runs_the_package_as_wmr_run_does(built: BuildResult, tmp_path: Path,
                                                      start: Pose | None, fmi: int) -> None:
    """The robot's path in OMSimulator is ``wmr run``'s within the CSV's 12 digits (x, y and
    theta in their own columns), it converges at ``wmr run``'s sample, runs to the package's
    stop time (it ignores the controller's stop request) and ends held by the brake; the
    variant's start and goal reach it (parameter sets and the FMUs' start values), under a
    name that is not an OMSimulator identifier; FMI 2.0 and 3.0 alike."""
    from wmr.adapters.ssp.omsimulator import converged_at_s, simulate_omsimulator

    version = _omsimulator_or_skip()
    spec = _spec(start=start, goal=Pose(-1.0, 0.5, math.radians(-60.0)) if start else
                 _NEAR_GOAL)
    if start is not None:
        spec = replace(spec, name="oms-variant_0.5")  # as wmr names a variant: '-' and '.'
    package = _package(built, spec, tmp_path, fmi)
    with unpacked_package(package) as (pkg, folder):
        result, ref = wmr_run(spec, folder / pkg.component(ROBOT).source)
    assert result.status == "converged"
    run = simulate_omsimulator(package)
    assert run.master == version
    h = spec.period_s
    assert len(run.block) == round(spec.t_max_s / h) + 1  # to the stop time, not the goal
    path = run.block[:, :3]
    pos_m, head_rad = deviation(path, ref)
    assert pos_m < 1e-9 and head_rad < 1e-9, (pos_m, head_rad)
    assert converged_at_s(run) == pytest.approx(result.time_to_goal_s, abs=h / 2)
    end, goal = path[-1], spec.goal
    assert math.hypot(end[0] - goal.x_m, end[1] - goal.y_m) < spec.stop_radius_m
    # braked after converging: within the bars of where wmr run stopped
    assert math.hypot(*(end[:2] - ref[-1, :2])) < 5e-3
    assert abs(end[2] - ref[-1, 2]) < math.radians(0.2)
    assert run.extra["model_name"] == ("oms" if start is None else "oms_variant_0_5")


def test_wmr_ssp_check_has_omsimulator_s_row(built: BuildResult, tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """The row's figures are those of the agreement helpers on OMSimulator's own run."""
    from wmr.adapters.ssp.omsimulator import simulate_omsimulator
    from wmr.apps import ssp_check
    from wmr.apps.ssp_check import MASTERS, check_package

    version = _omsimulator_or_skip()
    # the other masters are tested in test_ssp.py
    monkeypatch.setattr(ssp_check, "MASTERS", {"omsimulator": MASTERS["omsimulator"]})
    spec = _spec()
    package = _package(built, spec, tmp_path)
    report = check_package(package)
    (row,) = [r for r in report.rows if r.master.startswith("omsimulator")]
    assert row.master == f"omsimulator ({version})" and row.fmi_version == "2.0"
    assert row.ran and row.agrees and row.said == "ok" and row.lag_steps == 0
    assert row.converged_at_s == report.reference.converged_at_s
    path = simulate_omsimulator(package).block[:, :3]
    with unpacked_package(package) as (pkg, folder):
        _, ref = wmr_run(spec, folder / pkg.component(ROBOT).source)
    assert row.final_distance_mm == pytest.approx(
        1e3 * math.hypot(*(path[-1, :2] - ref[-1, :2])), rel=1e-9)
    assert row.worst_distance_mm is not None and row.worst_distance_mm < 1e-6


def test_omsimulator_model_names_are_its_identifiers() -> None:
    """OMSimulator takes ``^[a-zA-Z][a-zA-Z0-9_]*$`` as a model name (ComRef.cpp): a
    package's name is kept when it is one, else every other character becomes ``_``."""
    from wmr.adapters.ssp.omsimulator import model_name
    from wmr.adapters.ssp.package import SspPackage

    def name(n: str) -> str:
        return model_name(SspPackage(path=Path("p.ssp"), name=n, components={},
                                     start_time_s=0.0, stop_time_s=1.0, step_size_s=0.01))

    assert name("fig11") == "fig11"
    assert name("fig11-from_3_-2_170deg-to_-4_5_-60deg") == \
        "fig11_from_3__2_170deg_to__4_5__60deg"
    assert name("9lives.x") == "p_9lives_x"
    assert name("élan") == "p__lan"


def test_omsimulator_s_row_says_why_it_is_not_importable(
        built: BuildResult, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Where OMSimulator is absent (here: hidden), its row says why and is not counted."""
    from wmr.apps import ssp_check
    from wmr.apps.ssp_check import MASTERS, check_package

    monkeypatch.setitem(sys.modules, "OMSimulator", None)  # import raises ImportError
    # the other masters are tested in test_ssp.py
    monkeypatch.setattr(ssp_check, "MASTERS", {"omsimulator": MASTERS["omsimulator"]})
    report = check_package(_package(built, _spec(), tmp_path))
    (row,) = report.rows
    assert row.master == "omsimulator" and not row.ran and row.agrees is None
    assert row.said.startswith("OMSimulator not importable: "), row.said
    assert "docs/ssp.md" in row.said
    assert not report.agrees  # no master ran


def test_omsimulator_s_result_columns_are_read_by_name(tmp_path: Path) -> None:
    """OMSimulator's CSV layout (header ``time,<system>.<component>.<variable>``, ``", "``
    between values, two rows at a time where it passed values on): each variable from its own
    column, the last row of each time kept; a missing column is one error naming it."""
    from wmr.adapters.ssp.omsimulator import read_result
    from wmr.adapters.ssp.package import SspPackage
    from wmr.infra.errors import FmuError

    csv = tmp_path / "result.csv"
    csv.write_text("time,sys.robot.y,sys.controller.converged,sys.robot.x\n"
                   "0, 2, 0, 1\n0.01, 2.5, 0, 1.5\n0.01, 2.5, 1, 1.5\n0.02, 3, 1, 2\n")
    package = SspPackage(path=csv, name="p", components={}, start_time_s=0.0,
                         stop_time_s=0.02, step_size_s=0.01)
    times, values = read_result(csv, {"robot": ["x", "y"], "controller": ["converged"]},
                                package)
    np.testing.assert_array_equal(times, [0.0, 0.01, 0.02])
    np.testing.assert_array_equal(values["robot"]["x"], [1.0, 1.5, 2.0])
    np.testing.assert_array_equal(values["robot"]["y"], [2.0, 2.5, 3.0])
    np.testing.assert_array_equal(values["controller"]["converged"], [0.0, 1.0, 1.0])
    with pytest.raises(FmuError, match=r"0 columns of robot\.theta, not 1"):
        read_result(csv, {"robot": ["theta"]}, package)

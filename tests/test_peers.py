"""The peer stabilisers (Astolfi's polar law, Park & Kuipers' graceful law) on the FMU."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.config.scenario import Overrides, load_scenario, parse_scenario, with_overrides
from wmr.core.closedloop import run_closed_loop
from wmr.core.control import Limits, ServoedController
from wmr.core.control.from_spec import SpecController
from wmr.core.control.peers import (
    AstolfiGains,
    AstolfiStabiliser,
    GracefulGains,
    GracefulStabiliser,
)
from wmr.core.control.registry import make_controller
from wmr.core.plant import Pose, RobotParams
from wmr.core.runlog import MemoryLog
from wmr.core.runspec import RunSpec
from wmr.core.signals import COLUMN
from wmr.infra.errors import ConfigError

CASES = {
    "ahead": (Pose(0.0, 0.0, 0.0), Pose(8.0, 2.0, math.radians(20.0))),
    "behind": (Pose(0.0, 0.0, 0.0), Pose(-6.0, 1.0, 0.0)),
    "fig11": (Pose(0.0, 0.0, 0.0), Pose(20.0, 10.0, 0.0)),
}



@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("controller", ["astolfi", "graceful"])
def test_peer_converges_on_the_fmu(fmu3_plant: FmuPlant, controller: str, case: str) -> None:
    start, goal = CASES[case]
    spec = RunSpec(name=case, start=start, goal=goal, controller=controller, t_max_s=80.0)
    keep = MemoryLog()
    r = run_closed_loop(spec, fmu3_plant, sink=keep, controller=SpecController())
    assert r.status == "converged", r.message
    assert r.final_position_error_m <= spec.stop_radius_m
    assert r.final_heading_error_rad <= spec.heading_tolerance_rad + 1e-12
    rows = keep.block
    lim = Limits()
    # the same servos and limits as the PI: torque and wheel references within the limits
    assert np.nanmax(np.abs(rows[:, COLUMN["tau_r_nm"]])) <= lim.torque_max_nm + 1e-9
    assert np.nanmax(np.abs(rows[:, COLUMN["omega_r_ref_radps"]])) <= \
        lim.wheel_speed_max_radps + 1e-9
    assert np.nanmax(np.abs(rows[:, COLUMN["u_s_mps"]])) <= lim.v_max_mps + 1e-9
    assert np.nanmax(np.abs(rows[:, COLUMN["u_theta_radps"]])) <= lim.omega_max_radps + 1e-9
    # no integral terms in the peers
    assert np.all(np.isnan(rows[:, COLUMN["i_s_mps"]]))


def test_astolfi_reverses_to_a_goal_behind_and_graceful_does_not(fmu3_plant: FmuPlant) -> None:
    start, goal = CASES["behind"]
    v_min = {}
    for controller in ("astolfi", "graceful"):
        keep = MemoryLog()
        spec = RunSpec(name="behind", start=start, goal=goal, controller=controller)
        assert run_closed_loop(spec, fmu3_plant, sink=keep,
                               controller=SpecController()).status == "converged"
        v_min[controller] = float(np.min(keep.block[:, COLUMN["v_mps"]]))
    assert v_min["astolfi"] < -0.5  # the book's backward frame
    assert v_min["graceful"] > -0.05  # forward only (the alignment may creep a few mm/s)


def test_astolfi_without_reverse_drives_forward(fmu3_plant: FmuPlant) -> None:
    start, goal = CASES["behind"]
    keep = MemoryLog()
    spec = RunSpec(name="behind", start=start, goal=goal, controller="astolfi",
                   controller_gains=(("reverse", 0.0),))
    assert run_closed_loop(spec, fmu3_plant, sink=keep,
                           controller=SpecController()).status == "converged"
    assert float(np.min(keep.block[:, COLUMN["v_mps"]])) > -0.05


def test_limits_scale_v_and_omega_together_keeping_the_curvature() -> None:
    g = AstolfiGains()
    st = AstolfiStabiliser(Pose(20.0, 10.0, 0.0), g, Limits(), RobotParams(), 0.01, 0.05)
    out = st.update(0.0, 0.0, 0.0)
    v, w = out[6], out[7]
    rho = math.hypot(20.0, 10.0)
    alpha = math.atan2(10.0, 20.0)
    beta = -alpha
    assert v == pytest.approx(Limits().v_max_mps)
    assert w / v == pytest.approx((g.k_alpha * alpha + g.k_beta * beta) / (g.k_rho * rho))


def test_graceful_curvature_is_park_and_kuipers() -> None:
    g = GracefulGains()
    st = GracefulStabiliser(Pose(3.0, 4.0, 1.0), g, Limits(v_max_mps=10.0, omega_max_radps=50.0,
                                                             wheel_speed_max_radps=1e3),
                            RobotParams(), 0.01, 0.05)
    theta = 0.2
    out = st.update(0.0, 0.0, theta)
    los = math.atan2(4.0, 3.0)
    r, phi, delta = 5.0, 1.0 - los, theta - los
    kappa = -(g.k_delta * (delta - math.atan(-g.k_phi * phi))
              + (1 + g.k_phi / (1 + (g.k_phi * phi) ** 2)) * math.sin(delta)) / r
    v = 10.0 / (1 + g.beta * abs(kappa) ** g.lam)
    assert out[6] == pytest.approx(v)
    assert out[7] == pytest.approx(kappa * v)
    assert out[4] == pytest.approx(phi) and out[2] == pytest.approx(delta)


@pytest.mark.parametrize(("name", "gains"), [
    ("astolfi", {"k_beta": 0.5}),
    ("astolfi", {"k_alpha": 1.0, "k_rho": 3.0}),
    ("astolfi", {"k_nope": 1.0}),
    ("graceful", {"k_delta": -1.0}),
    ("pi", {"K_ps": 1.0}),
    ("lqr", {}),
])
def test_bad_controller_or_gains_are_config_errors(name: str, gains: dict[str, float]) -> None:
    with pytest.raises(ConfigError):
        make_controller(RunSpec(name="bad", start=Pose(0.0, 0.0, 0.0), goal=Pose(1.0, 0.0, 0.0),
                                controller=name, controller_gains=tuple(gains.items())))


def test_scenario_selects_a_peer_and_overrides_switch_it() -> None:
    sc = parse_scenario({"name": "t", "start": [0, 0, 0], "goal": [5, 0, 0],
                         "controller": "graceful", "controller_gains": {"k_phi": 1.5}})
    spec = sc.runs[0]
    assert spec.controller == "graceful" and dict(spec.controller_gains) == {"k_phi": 1.5}
    c = make_controller(spec)
    assert isinstance(c, ServoedController) and isinstance(c.stabiliser, GracefulStabiliser)
    assert c.stabiliser.k_phi == 1.5
    a = with_overrides(spec, Overrides(controller="astolfi"))
    assert a.controller == "astolfi" and a.controller_gains == ()
    with pytest.raises(ConfigError):
        parse_scenario({"name": "t", "start": [0, 0, 0], "goal": [5, 0, 0],
                        "controller": "astolfi", "controller_gains": {"k_phi": 1.5}})
    # the shipped scenarios still default to the PI
    assert all(r.controller == "pi" for r in load_scenario("fig9").runs)
    assert replace(spec, controller="pi", controller_gains=()).controller == "pi"

"""The CasADi/IPOPT optimal reference (:mod:`wmr.adapters.ocp`).

The OCP must run on the Modelica model's own equations: the first tests integrate the flattened
model (CVODES and the OCP's RK4) and the FMU from the same torques and compare every output.
The solves below reuse one NLP per process (60 intervals); the full Fig. 9 + Fig. 10 sweep is
marked slow.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wmr.adapters import ocp as optimal
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.ocp import (
    OptimalLimits,
    OptimalProblem,
    OptimalResult,
    SolverOptions,
    fig9_cases,
    fig10_cases,
    replay_open_loop,
    simulate,
    solve_optimal,
)
from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams
from wmr.infra.errors import ConfigError

START = Pose(0.0, 0.0, 0.0)
FIG11_GOAL = Pose(20.0, 10.0, 0.0)
#: The closed loop's limits (wmr.core.control.Limits defaults), so that the limited paths are
#: tested.
CLOSED_LOOP = OptimalLimits(torque_max_nm=8.0, wheel_speed_max_radps=10.0, v_max_mps=1.0,
                            omega_max_radps=1.5)
P = RobotParams()
M11 = P.m + 2 * P.Iwm / P.r**2


@pytest.fixture(scope="module")
def fig11() -> OptimalResult:
    return solve_optimal(OptimalProblem(START, FIG11_GOAL))


@pytest.fixture(scope="module")
def fig11_limited() -> OptimalResult:
    return solve_optimal(OptimalProblem(START, FIG11_GOAL, limits=CLOSED_LOOP))


def _torque_sequence(n: int) -> np.ndarray:
    k = np.arange(n)
    return np.column_stack([3.0 * np.sin(0.11 * k) + 1.0, 2.0 * np.cos(0.07 * k) - 0.5])


# --- the OCP's model is the FMU's model ------------------------------------------------------


def _fmu_run(plant: FmuPlant, params: RobotParams, start: Pose, torques: np.ndarray,
             h: float) -> np.ndarray:
    rows = [plant.reset(params, start).copy()]
    for tau_r, tau_l in torques:
        rows.append(plant.step(float(tau_r), float(tau_l), h).copy())
    return np.array(rows)


def test_ocp_model_and_fmu_integrate_to_the_same_outputs(plant: FmuPlant) -> None:
    """CVODES on ``model.ode`` (the function the OCP uses) against the FMU, every output."""
    params = RobotParams(m=30.0, l=0.2, Iwm=0.02, b_f=0.05, tau_c=0.2, w_c=0.5)
    start = Pose(1.0, -2.0, 0.3)
    h, torques = 0.05, _torque_sequence(120)
    model = optimal._model()
    x = ca.SX.sym("x", len(model.state_names))
    u, p = ca.SX.sym("u", 2), ca.SX.sym("p", len(model.param_names))
    F = ca.integrator("F", "cvodes", {"x": x, "p": ca.vertcat(u, p),
                                      "ode": model.ode(x, u, p)},
                      0.0, h, {"abstol": 1e-12, "reltol": 1e-12})
    pv = model.param_vector(params, start)
    xk = np.asarray(model.init(pv)).ravel()
    xs = [xk]
    for tau in torques:
        xk = np.asarray(F(x0=xk, p=np.concatenate([tau, pv]))["xf"]).ravel()
        xs.append(xk)
    us = np.vstack([torques, torques[-1]])
    y = np.array([np.asarray(model.out(xi, ui, pv)).ravel() for xi, ui in zip(xs, us,
                                                                              strict=True)])
    ocp = {name: y[:, i] for i, name in enumerate(model.output_names)}
    fmu = _fmu_run(plant, params, start, torques, h)
    assert abs(ocp["x"][-1] - start.x_m) > 1.0  # the run goes somewhere
    for i, name in enumerate(OUTPUT_NAMES):
        np.testing.assert_allclose(fmu[:, i], ocp[name], rtol=1e-7, atol=1e-7, err_msg=name)


def test_ocp_rk4_agrees_with_the_fmu_to_its_own_accuracy(plant: FmuPlant) -> None:
    """The OCP's RK4 (4 sub-steps per 0.05 s) against the FMU's tight DOPRI5."""
    h, torques = 0.05, _torque_sequence(120)
    rk = simulate(START, torques, h, P, rk_substeps=4)
    fmu = _fmu_run(plant, P, START, torques, h)
    idx = {n: i for i, n in enumerate(OUTPUT_NAMES)}
    for state, out in (("x", "x"), ("y", "y"), ("theta", "theta"), ("v", "v"),
                       ("omega", "omega"), ("wheelR.phi", "phi_r"), ("wheelL.phi", "phi_l")):
        np.testing.assert_allclose(rk[state], fmu[:, idx[out]], atol=1e-5, err_msg=state)


def test_parameters_reach_the_model_by_name() -> None:
    model = optimal._model()
    pv = model.param_vector(RobotParams(m=31.0, L=0.4), Pose(1.0, 2.0, 3.0))
    named = dict(zip(model.param_names, pv.tolist(), strict=True))
    assert named["m"] == 31.0 and named["L"] == 0.4
    assert (named["x0"], named["y0"], named["theta0"]) == (1.0, 2.0, 3.0)
    assert set(RobotParams().as_dict()) <= set(model.param_names)


# --- minimum time, Fig. 11 case --------------------------------------------------------------


def _end(result: OptimalResult) -> tuple[float, float, float, float]:
    s = result.states
    pos = math.hypot(s["x"][-1] - result.goal.x_m, s["y"][-1] - result.goal.y_m)
    head = optimal._wrap(s["theta"][-1] - result.goal.heading_rad)
    return pos, head, s["v"][-1], s["omega"][-1]


def test_min_time_fig11_reaches_the_goal_at_rest_within_the_limits(fig11: OptimalResult) -> None:
    assert fig11.status == "solved", fig11.message
    pos, head, v, w = _end(fig11)
    assert pos < 1e-6 and abs(head) < 1e-6 and abs(v) < 1e-9 and abs(w) < 1e-9
    assert np.max(np.abs(fig11.torques)) <= 10.0 + 1e-6
    # time-optimal: the torques sit on their limits most of the time (bang-bang)
    assert np.mean(np.abs(fig11.torques) > 9.9) > 0.7
    # no faster than a bang-bang straight line at full torque on both wheels
    d = math.hypot(20.0, 10.0)
    t_lower = 2.0 * math.sqrt(d / (2 * 10.0 / (P.r * M11)))
    assert t_lower <= fig11.final_time_s < 1.2 * t_lower
    assert d <= fig11.path_length_m < 1.05 * d
    assert fig11.t_s[-1] == pytest.approx(fig11.final_time_s)
    assert fig11.torques.shape == (optimal.DEFAULT_INTERVALS, 2)


def test_min_time_under_closed_loop_limits_honours_them(fig11_limited: OptimalResult) -> None:
    r = fig11_limited
    assert r.status == "solved", r.message
    assert np.max(np.abs(r.torques)) <= 8.0 + 1e-6
    assert np.max(np.abs(r.states["v"])) <= 1.0 + 1e-6
    assert np.max(np.abs(r.states["omega"])) <= 1.5 + 1e-6
    # the speed limit dominates: at least distance / v_max
    assert r.final_time_s >= math.hypot(20.0, 10.0) / 1.0
    assert r.max_wheel_speed_radps <= 10.0 * 1.02  # nodes exact, in between nearly


def test_heading_180_and_minus_180_are_the_same_goal() -> None:
    a = solve_optimal(OptimalProblem(Pose(10.0, 0.0, 0.0), Pose(0.0, 0.0, math.pi)))
    b = solve_optimal(OptimalProblem(Pose(10.0, 0.0, 0.0), Pose(0.0, 0.0, -math.pi)))
    assert a.status == b.status == "solved"
    assert a.final_time_s == pytest.approx(b.final_time_s, rel=1e-6)


def test_energy_and_mix_objectives_trade_time_for_effort(fig11: OptimalResult) -> None:
    energy = solve_optimal(OptimalProblem(START, FIG11_GOAL, objective="energy",
                                          final_time_s=8.0))
    mix = solve_optimal(OptimalProblem(START, FIG11_GOAL, objective="mix"))
    assert energy.status == mix.status == "solved"
    assert energy.final_time_s == 8.0 and _end(energy)[0] < 1e-6
    assert energy.effort_N2m2s < 0.5 * fig11.effort_N2m2s
    assert mix.final_time_s > fig11.final_time_s
    assert mix.effort_N2m2s < fig11.effort_N2m2s


def test_forward_only_by_default_and_reversing_when_allowed() -> None:
    # facing away from the goal: reversing down the y axis is quicker than turning first
    start, goal = Pose(0.0, 10.0, math.pi / 2), Pose(0.0, 0.0, math.pi)
    fwd = solve_optimal(OptimalProblem(start, goal))
    rev = solve_optimal(OptimalProblem(start, goal, allow_reverse=True))
    assert fwd.status == rev.status == "solved"
    assert np.min(fwd.states["v"]) >= -1e-9
    assert np.min(rev.states["v"]) < -1.0
    assert rev.final_time_s < fwd.final_time_s


@pytest.mark.parametrize("heading_deg", [10.0, -45.0, 90.0, -135.0, 180.0])
def test_turns_on_the_spot_solve_and_replay_on_the_fmu(heading_deg: float, fmu3: Path) -> None:
    """Issue 21: from 10 to 90 deg either way IPOPT ended in Maximum_Iterations_Exceeded
    (v = 0 at every node sat on the bound v >= 0 and the goal pinned x, y too)."""
    from wmr.adapters.ocp import SPOT_TURN_CREEP_MPS

    turn = math.radians(heading_deg)
    r = solve_optimal(OptimalProblem(START, Pose(0.0, 0.0, turn), limits=CLOSED_LOOP))
    assert r.status == "solved", r.message
    # no faster than turning at the omega limit, and at most the PI's 2.98 s for 90 deg
    assert CLOSED_LOOP.omega_max_radps is not None
    assert abs(turn) / CLOSED_LOOP.omega_max_radps <= r.final_time_s
    assert r.final_time_s < 2.98 * abs(turn) / (math.pi / 2) + 0.5
    assert np.min(r.states["v"]) >= -SPOT_TURN_CREEP_MPS - 1e-9
    assert np.max(np.hypot(r.states["x"], r.states["y"])) < 0.02  # it stays on the spot
    rp = replay_open_loop(r, fmu3)
    assert rp.final_position_error_m < 0.01
    assert abs(rp.final_heading_error_rad) < 0.01


def test_short_moves_stay_forward_only() -> None:
    """The creep is for turns on the spot only: a goal 0.5 m away keeps v >= 0."""
    r = solve_optimal(OptimalProblem(START, Pose(0.0, 0.5, math.pi / 2), limits=CLOSED_LOOP))
    assert r.status == "solved"
    assert np.min(r.states["v"]) >= -1e-9


def test_a_solve_reports_its_progress(monkeypatch: pytest.MonkeyPatch) -> None:
    """A failing solve grinds for up to max_cpu_time_s: IPOPT's iterations are reported every
    PROGRESS_INTERVAL_S (0 here: every iteration)."""
    from wmr.adapters.ocp import transcription

    monkeypatch.setattr(transcription, "PROGRESS_INTERVAL_S", 0.0)
    lines: list[str] = []
    r = solve_optimal(OptimalProblem(START, FIG11_GOAL), progress=lines.append)
    iterations = [line for line in lines if line.startswith("IPOPT: iteration ")]
    assert r.status == "solved" and len(iterations) >= r.iterations
    assert "T = " in iterations[-1]
    lines.clear()
    # no receiver: silent, and the last one is forgotten
    solve_optimal(OptimalProblem(START, FIG11_GOAL))
    assert lines == []


# --- replay on the FMU -----------------------------------------------------------------------


def test_replay_of_fig11_ends_within_0_1_m(fig11: OptimalResult, plant: FmuPlant) -> None:
    rp = replay_open_loop(fig11, plant)
    assert rp.final_position_error_m < 0.1
    assert abs(rp.final_heading_error_rad) < 0.01
    assert abs(rp.final_speed_mps) < 0.01 and abs(rp.final_omega_radps) < 0.01
    # sub-stepped: every FMU step at most 10 ms, and the replay lasts T
    assert np.max(np.diff(rp.t_s)) <= 0.01 + 1e-12
    assert rp.t_s[-1] == pytest.approx(fig11.final_time_s)
    # the OCP's own discretisation check predicts the replay's miss
    assert rp.final_position_error_m == pytest.approx(fig11.rollout_error_m, rel=0.2, abs=1e-6)


def test_replay_under_limits_within_0_1_m_and_below_the_wheel_limit(
        fig11_limited: OptimalResult, fmu3: Path) -> None:
    rp = replay_open_loop(fig11_limited, fmu3)
    assert rp.final_position_error_m < 0.1
    wheel = np.maximum(np.abs(rp.outputs["omega_r"]), np.abs(rp.outputs["omega_l"]))
    assert np.max(wheel) <= 10.0 * 1.02


def test_replay_refuses_an_unsolved_result(fmu3: Path) -> None:
    bad = solve_optimal(OptimalProblem(START, FIG11_GOAL, limits=OptimalLimits(0.0)))
    with pytest.raises(ConfigError, match=r"result\.status"):
        replay_open_loop(bad, fmu3)


# --- clear outcomes --------------------------------------------------------------------------


def test_zero_torque_is_infeasible_at_once() -> None:
    r = solve_optimal(OptimalProblem(START, FIG11_GOAL, limits=OptimalLimits(0.0)))
    assert r.status == "infeasible"
    assert "torque" in r.message
    assert r.iterations == 0 and not math.isfinite(r.final_time_s)
    assert r.summary()["final_time_s"] is None


def test_too_short_final_time_is_infeasible_not_a_hang() -> None:
    # the minimum time of this manoeuvre is about 4.5 s
    r = solve_optimal(OptimalProblem(START, FIG11_GOAL, objective="energy", final_time_s=3.0),
                      SolverOptions(max_cpu_time_s=20.0))
    assert r.status == "infeasible", r.message
    assert "final_time_s" in r.message
    assert r.solve_time_s < 20.0


def test_start_equal_to_goal_is_trivial() -> None:
    r = solve_optimal(OptimalProblem(Pose(1.0, 2.0, 0.5), Pose(1.0, 2.0, 0.5 + 2 * math.pi)))
    assert r.status == "solved"
    assert r.final_time_s == 0.0 and r.path_length_m == 0.0 and r.iterations == 0
    assert r.torques.shape == (0, 2)
    assert r.states["x"].tolist() == [1.0]


def test_energy_needs_a_final_time() -> None:
    with pytest.raises(ConfigError) as err:
        solve_optimal(OptimalProblem(START, FIG11_GOAL, objective="energy"))
    assert err.value.field == "final_time_s"
    with pytest.raises(ConfigError) as err:
        solve_optimal(OptimalProblem(START, FIG11_GOAL, objective="time", final_time_s=5.0))
    assert err.value.field == "final_time_s"


@pytest.mark.parametrize(("problem", "options", "field"), [
    ({"goal": Pose(math.nan, 10.0, 0.0)}, {}, "goal.x_m"),
    ({"start": Pose(0.0, 0.0, math.inf)}, {}, "start.heading_rad"),
    ({"limits": {"torque_max_nm": -1.0}}, {}, "limits.torque_max_nm"),
    ({"limits": {"wheel_speed_max_radps": math.nan}}, {}, "limits.wheel_speed_max_radps"),
    ({"objective": "fast"}, {}, "objective"),
    ({"mix_weight": -1.0}, {}, "mix_weight"),
    ({}, {"n_intervals": 1}, "n_intervals"),
    ({}, {"max_iter": 0}, "max_iter"),
])
def test_bad_input_names_the_field(problem: dict[str, object], options: dict[str, object],
                                   field: str) -> None:
    args: dict[str, object] = {"start": START, "goal": FIG11_GOAL, **problem}
    with pytest.raises(ConfigError) as err:
        if isinstance(args.get("limits"), dict):
            args["limits"] = OptimalLimits(**args["limits"])  # type: ignore[arg-type]
        solve_optimal(OptimalProblem(**args), SolverOptions(**options))  # type: ignore[arg-type]
    assert err.value.field == field


def test_limits_like_reads_the_closed_loop_fields() -> None:
    other = SimpleNamespace(torque_max_nm=8.0, wheel_speed_max_radps=10.0, v_max_mps=1.0,
                            omega_max_radps=1.5, unrelated=3)
    lim = OptimalLimits.like(other)
    assert lim == OptimalLimits(8.0, 10.0, 1.0, 1.5)
    with pytest.raises(ConfigError, match=r"limits\.torque_max_nm"):
        OptimalLimits(torque_max_nm=-2.0)


# --- the warm start --------------------------------------------------------------------------

angles = st.floats(-math.pi, math.pi)
coords = st.floats(-15.0, 15.0)


@settings(max_examples=30, deadline=None)
@given(coords, coords, angles, coords, coords, angles)
def test_kinematic_guess_joins_start_and_goal(x0: float, y0: float, h0: float, x1: float,
                                              y1: float, h1: float) -> None:
    start, goal = Pose(x0, y0, h0), Pose(x1, y1, h1)
    model = optimal._model()
    n = 20
    lim = OptimalLimits(torque_max_nm=5.0)
    g = optimal._kinematic_guess(start, goal, P, lim, n, None, model.param_vector(P, start))
    nx = len(model.state_names)
    xs = g.w0[:nx * (n + 1)].reshape(nx, n + 1, order="F")
    us = g.w0[nx * (n + 1):-1]
    first, last = xs[:, 0], xs[:, -1]
    assert (first[model.sx("x")], first[model.sx("y")]) == pytest.approx((x0, y0), abs=1e-9)
    assert (last[model.sx("x")], last[model.sx("y")]) == pytest.approx((x1, y1), abs=1e-6)
    assert abs(optimal._wrap(last[model.sx("theta")] - h1)) < 1e-6
    assert abs(last[model.sx("v")]) < 1e-9 and abs(last[model.sx("omega")]) < 1e-9
    assert np.all(np.abs(us) <= 5.0) and g.final_time_s > 0.0


@pytest.mark.slow
@pytest.mark.parametrize("limits", [OptimalLimits(), CLOSED_LOOP],
                         ids=["torque-only", "closed-loop"])
def test_warm_start_solves_every_fig9_and_fig10_case(limits: OptimalLimits,
                                                     fmu3: Path) -> None:
    cases = fig9_cases() + fig10_cases((0.0, 90.0, 180.0, -90.0))
    failed, far = [], []
    with FmuPlant(fmu3) as plant:
        for name, start, goal in cases:
            r = solve_optimal(OptimalProblem(start, goal, limits=limits))
            if r.status != "solved":
                failed.append(f"{name}: {r.message}")
                continue
            rp = replay_open_loop(r, plant)
            if rp.final_position_error_m >= 0.1:
                far.append(f"{name}: {rp.final_position_error_m:.3g} m")
    assert not failed, failed
    assert not far, far


def test_the_optimal_record_has_one_effort_and_an_absolute_heading_error(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, fmu3: Path) -> None:
    """``wmr optimal --json``: docs/results.md defines final_heading_error_rad as |theta -
    theta_d|, and the effort is torque_sq_integral_n2m2s alone (issue 21 found a signed error
    and a duplicate effort_N2m2s)."""
    import dataclasses

    from wmr.apps.optimal import optimal_limits, optimal_to_log

    real = optimal.replay_open_loop

    def tilted(*args: object, **kwargs: object) -> object:
        rp = real(*args, **kwargs)  # type: ignore[arg-type]
        return dataclasses.replace(rp, final_heading_error_rad=-0.01)

    monkeypatch.setattr(optimal, "replay_open_loop", tilted)
    record = optimal_to_log(OptimalProblem(START, Pose(2.0, 1.0, 0.0), limits=optimal_limits()),
                            tmp_path / "o.mcap", fmu3, name="t")
    assert record["status"] == "solved"
    assert record["final_heading_error_rad"] == pytest.approx(0.01)
    assert "effort_N2m2s" not in record and record["torque_sq_integral_n2m2s"] > 0.0


# --- the results that need no NLP, and the JSON summary (survivors of the mutation run) ----

#: The JSON fields of ``OptimalResult.summary`` (``wmr optimal`` prints and logs them).
_SUMMARY_FIELDS = {"status", "message", "objective", "final_time_s", "path_length_m",
                   "energy_positive_j", "effort_N2m2s", "solve_time_s", "iterations",
                   "n_intervals", "limits"}
_METRICS = ("path_length_m", "energy_positive_j", "effort_N2m2s", "max_wheel_speed_radps",
            "rollout_error_m")


def test_a_trivial_result_is_the_start_at_rest_at_no_cost() -> None:
    """Start equal to goal: one node, the start's own state at rest, every cost 0, and the
    inputs carried through (a robot and a torque limit of its own)."""
    params = replace(RobotParams(), m=30.0)
    start = Pose(1.0, 2.0, 0.5)
    r = solve_optimal(OptimalProblem(start, Pose(1.0, 2.0, 0.5 + 2 * math.pi), params,
                                     limits=OptimalLimits(7.0)))
    assert (r.status, r.objective, r.start, r.params) == ("solved", "time", start, params)
    assert r.goal == Pose(1.0, 2.0, 0.5 + 2 * math.pi)
    assert r.limits.torque_max_nm == 7.0
    assert r.t_s.tolist() == [0.0] and r.interval_s == 0.0
    at_rest = {"x": 1.0, "y": 2.0, "theta": 0.5, "v": 0.0, "omega": 0.0}
    assert {n: r.states[n].tolist() for n in at_rest} == {n: [v] for n, v in at_rest.items()}
    assert all(a.shape == (1,) for a in r.states.values())
    assert all(getattr(r, m) == 0.0 for m in _METRICS)
    assert (r.solve_time_s, r.iterations) == (0.0, 0)
    s = r.summary()
    assert set(s) == _SUMMARY_FIELDS
    assert (s["status"], s["objective"], s["message"]) == ("solved", "time", r.message)
    assert (s["path_length_m"], s["energy_positive_j"], s["effort_N2m2s"]) == (0.0, 0.0, 0.0)
    assert (s["final_time_s"], s["solve_time_s"], s["iterations"], s["n_intervals"]) == (
        0.0, 0.0, 0, 0)
    assert s["limits"]["torque_max_nm"] == 7.0
    json.dumps(s, allow_nan=False)


def test_an_infeasible_result_has_no_trajectory_and_no_numbers() -> None:
    """Zero torque: no node, no state, every cost NaN (None in JSON), nothing solved."""
    r = solve_optimal(OptimalProblem(START, FIG11_GOAL, objective="energy",
                                     limits=OptimalLimits(0.0), final_time_s=5.0))
    assert (r.status, r.objective, r.start, r.goal) == ("infeasible", "energy", START,
                                                        FIG11_GOAL)
    assert r.params == RobotParams() and r.limits.torque_max_nm == 0.0
    assert r.t_s.shape == (0,) and r.torques.shape == (0, 2)
    assert all(a.shape == (0,) for a in r.states.values())
    assert all(math.isnan(getattr(r, m)) for m in _METRICS)
    assert (r.solve_time_s, r.iterations) == (0.0, 0)
    s = r.summary()
    assert set(s) == _SUMMARY_FIELDS
    assert s["status"] == "infeasible" and s["objective"] == "energy"
    assert [s[k] for k in ("path_length_m", "energy_positive_j", "effort_N2m2s")] == [None] * 3
    json.dumps(s, allow_nan=False)


def test_the_rollout_takes_ten_steps_per_interval() -> None:
    """docs/optimal.md: ``rollout_error_m`` integrates the torques with 10 times finer steps."""
    from wmr.adapters.ocp.result import _dense

    torques = np.array([[1.0, 0.5], [0.2, -0.3], [0.0, 0.0]])
    t, states, outputs = _dense(START, RobotParams(), torques, 0.1, 4)
    assert len(t) == len(states) == len(outputs) == 3 * 10 + 1
    assert t[-1] == pytest.approx(0.3, rel=1e-12)


def test_the_rollout_integrals_of_a_straight_run_by_hand() -> None:
    """Equal torques from rest, 2 then 1 N m a wheel over two intervals: a straight run with
    piecewise constant acceleration (tau_r + tau_l) / (r M11), so the path is x(T), all the
    work went into kinetic energy, the wheel speed peaks at v(T) / r."""
    from wmr.adapters.ocp.result import _integrals
    from wmr.core.physics import mass_matrix_diag

    p = RobotParams()
    m11 = mass_matrix_diag(p)[0]
    h = 0.5
    a1, a2 = 4.0 / (p.r * m11), 2.0 / (p.r * m11)
    v1 = a1 * h
    v2 = v1 + a2 * h
    x_end = a1 * h * h / 2 + v1 * h + a2 * h * h / 2
    goal = Pose(x_end + 0.3, 0.4, 0.0)
    length, work, w_max, miss = _integrals(START, goal, p, np.array([[2.0, 2.0], [1.0, 1.0]]),
                                           h, 4)
    assert length == pytest.approx(x_end, rel=1e-9)
    assert work == pytest.approx(0.5 * m11 * v2**2, rel=1e-9)
    assert w_max == pytest.approx(v2 / p.r, rel=1e-9)
    assert miss == pytest.approx(0.5, rel=1e-9)


def test_the_rollout_work_of_a_turning_run_is_its_kinetic_energy() -> None:
    """Unequal torques, every wheel power positive and no friction: the positive work is the
    kinetic energy at T, from an independent integration of the hand-written physics."""
    from scipy.integrate import solve_ivp

    from wmr.adapters.ocp.result import _integrals
    from wmr.core.physics import derivatives, kinetic_energy

    p = RobotParams()
    h, torques = 0.5, [(2.0, 1.0), (1.5, 0.5)]
    s = [0.0] * 7
    for tau in torques:
        s = solve_ivp(lambda _t, y, tau=tau: derivatives(y, *tau, p), (0.0, h), s,
                      method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    _, work, _, miss = _integrals(START, FIG11_GOAL, p, np.array(torques), h, 4)
    assert work == pytest.approx(kinetic_energy(s[3], s[4], p), rel=1e-3)
    # and the miss is the distance of the end of that run from the goal
    assert miss == pytest.approx(math.hypot(s[0] - FIG11_GOAL.x_m, s[1] - FIG11_GOAL.y_m),
                                 rel=1e-6)


@pytest.mark.parametrize("allow_reverse", [False, True])
def test_the_kinematic_warm_start_is_a_rest_to_rest_path_from_start_to_goal(
        allow_reverse: bool) -> None:
    """``ocp.warmstart._kinematic_guess``: the guess IPOPT starts from leaves the start and
    reaches the goal pose, at rest at both ends, within the torque limit, and its heading
    changes only as fast as its angular speed says (``d theta/dt = omega``, eq. 7, by the
    trapezoid rule over the nodes). Seen failing with the second rotation left out."""
    from wmr.adapters.ocp.model import _model
    from wmr.adapters.ocp.warmstart import _kinematic_guess

    m = _model()
    start, goal = Pose(0.0, 0.0, 0.0), Pose(-4.0, 3.0, math.radians(-60.0))
    params, limits, n = RobotParams(), OptimalLimits(8.0, 10.0, 1.0, 1.5), 60
    guess = _kinematic_guess(start, goal, params, limits, n, None,
                             m.param_vector(params, start), allow_reverse)
    nx = len(m.state_names)
    xs = guess.w0[: nx * (n + 1)].reshape((n + 1, nx)).T
    us = guess.w0[nx * (n + 1): nx * (n + 1) + 2 * n]
    ix, iy, ith, iv, iw = (m.sx(s) for s in ("x", "y", "theta", "v", "omega"))
    assert (xs[ix, 0], xs[iy, 0], xs[ith, 0]) == (0.0, 0.0, 0.0)
    assert xs[ix, -1] == pytest.approx(goal.x_m, abs=1e-9)
    assert xs[iy, -1] == pytest.approx(goal.y_m, abs=1e-9)
    turned = math.remainder(xs[ith, -1] - goal.heading_rad, 2 * math.pi)
    assert turned == pytest.approx(0.0, abs=1e-9)
    assert abs(xs[iv, 0]) + abs(xs[iw, 0]) + abs(xs[iv, -1]) + abs(xs[iw, -1]) < 1e-9
    assert np.all(np.abs(us) <= 8.0)
    h = guess.final_time_s / n
    heading_from_omega = np.concatenate(([0.0], np.cumsum(0.5 * h * (xs[iw, 1:] + xs[iw, :-1]))))
    assert np.max(np.abs(heading_from_omega - xs[ith])) < 0.05  # trapezoid rule, 60 nodes

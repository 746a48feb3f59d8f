"""Promises of the core checked against independent facts (issue 23, gaps 2, 6 and 8).

* ``--param`` reaches the plant: a run's logged states are what a fresh plant, given the
  overridden parameters and the run's own logged torques, produces (and not what the default
  robot produces from the same torques).
* The effort ``torque_sq_integral`` is :math:`\\int (\\tau_r^2 + \\tau_l^2)\\,dt` summed by
  hand from the logged torques, and so has the unit N^2 m^2 s (a lost ``* h`` is 100 times off).
* Conditional integration (anti-windup) of **both** PI channels of eq. 29, case by case.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from wmr.config.scenario import Overrides, expand, load_scenario, with_overrides
from wmr.core.closedloop import run_closed_loop
from wmr.core.control.from_spec import SpecController
from wmr.core.control.stabiliser import Gains, Limits, PointStabiliser
from wmr.core.physics import ReferencePlant
from wmr.core.plant import Plant, RobotParams
from wmr.core.runlog import MemoryLog
from wmr.core.runspec import RunSpec
from wmr.core.signals import COLUMN, PLANT_SIGNALS

_TAU = [COLUMN["tau_r_nm"], COLUMN["tau_l_nm"]]
_STATES = [COLUMN[name] for name in PLANT_SIGNALS]



def replay_torques(plant: Plant, params: RobotParams, spec: RunSpec,
                   rows: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """The plant outputs of a fresh ``plant`` with ``params`` driven by the logged torques
    (each held over one period, as the master holds them), one row per logged row."""
    out = [plant.reset(params, spec.start).copy()]
    for tau_r, tau_l in rows[:-1, _TAU]:
        out.append(plant.step(float(tau_r), float(tau_l), spec.period_s).copy())
    return np.vstack(out)


def _short_fig11(**params: float) -> RunSpec:
    (spec,) = expand(load_scenario("fig11"))
    return with_overrides(spec, Overrides(goal=(3.0, 0.0, 0.0), max_time_s=4.0, params=params))


# -- gap 2: parameter overrides reach the plant ----------------------------------------------


def test_parameter_overrides_drive_the_plant_not_just_the_spec() -> None:
    heavy = {"m": 40.0, "b_f": 0.02, "tau_c": 0.1}
    spec = _short_fig11(**heavy)
    rec = MemoryLog()
    run_closed_loop(spec, ReferencePlant(), rec, controller=SpecController())
    rows = rec.block
    assert rows.shape[0] > 100
    logged = rows[:, _STATES]
    # the same plant code with the overridden parameters repeats the run exactly ...
    same = replay_torques(ReferencePlant(), RobotParams(**heavy), spec, rows)
    np.testing.assert_array_equal(same, logged)
    # ... and the default robot, from the same torques, does not (the test can tell them apart)
    default = replay_torques(ReferencePlant(), RobotParams(), spec, rows)
    v = COLUMN["v_mps"]
    assert np.max(np.abs(default[:, v] - logged[:, v])) > 1e-3


# -- gap 6: the effort integral ----------------------------------------------------------------


@pytest.mark.parametrize("period_s", [0.01, 0.02])
def test_the_effort_is_the_integral_of_the_logged_torques_squared(period_s: float) -> None:
    (spec,) = expand(load_scenario("fig11"))
    spec = with_overrides(spec, Overrides(goal=(3.0, 1.0, 0.0), period_s=period_s))
    rec = MemoryLog()
    res = run_closed_loop(spec, ReferencePlant(), rec, controller=SpecController())
    assert res.status == "converged", res.message
    tau = rec.block[:, _TAU]
    # each logged torque is held over one period; the last row (at rest) applies none
    by_hand = 0.0
    for tau_r, tau_l in tau[:-1]:
        by_hand += (tau_r * tau_r + tau_l * tau_l) * period_s
    assert tau[-1].tolist() == [0.0, 0.0]
    assert res.torque_sq_integral == pytest.approx(by_hand, rel=1e-12)
    # the unit: a constant 1 N m on both wheels for T s gives 2 T N^2 m^2 s, so the effort of
    # this run lies between 0 and 2 T tau_max^2
    t_s = (tau.shape[0] - 1) * period_s
    assert 0.0 < res.torque_sq_integral <= 2.0 * t_s * spec.limits.torque_max_nm ** 2


# -- gap 8: anti-windup of both PI channels ------------------------------------------------------

_H = 0.01


def _stabiliser() -> PointStabiliser:
    # goal straight ahead along x, far away: alpha = beta = 0, so gamma = e_theta = -theta and
    # e_s = dr cos(gamma)
    return PointStabiliser(100.0, 0.0, 0.0, Gains(), Limits(), 0.15, 0.3, _H, 0.05)


def _drive(channel: str, integral: float, error: float) -> tuple[float, float, float]:
    """One update with the integral of ``channel`` preset and its error set to ``error``;
    returns (output, integral before, integral after)."""
    s = _stabiliser()
    if channel == "theta":
        s.i_theta = integral
        out = s.update(0.0, 0.0, -error)  # e_theta = gamma = -theta
        assert out[2] == pytest.approx(error)
        return out[7], integral, s.i_theta
    s.i_s = integral
    out = s.update(100.0 - error, 0.0, 0.0)  # e_s = dr = error (error > 0)
    assert out[1] == pytest.approx(error)
    return out[6], integral, s.i_s


_W = Limits().omega_max_radps


@pytest.mark.parametrize(("integral", "error", "limit", "integrates"), [
    (0.0, 0.05, None, True),  # inside the limits: integrates
    (0.0, -0.05, None, True),
    (2.0 * _W, 0.05, _W, False),  # at +limit and the error pushes further up: frozen
    (2.0 * _W, -0.05, _W, True),  # at +limit and the error pulls back: integrates
    (-2.0 * _W, -0.05, -_W, False),  # at -limit and pushing further down: frozen
    (-2.0 * _W, 0.05, -_W, True),  # at -limit and pulling back: integrates
], ids=["inside+", "inside-", "high-push", "high-pull", "low-push", "low-pull"])
def test_angle_channel_integrates_only_when_not_pushing_into_its_limit(
        integral: float, error: float, limit: float | None, integrates: bool) -> None:
    u, before, after = _drive("theta", integral, error)
    if limit is not None:
        assert u == limit
    else:
        assert abs(u) < _W
    k = Gains().K_itheta
    assert k > 0.0
    expected = before + k * error * _H if integrates else before
    assert after == pytest.approx(expected, rel=1e-12, abs=0.0)


_V = Limits().v_max_mps


@pytest.mark.parametrize(("integral", "error", "limit", "integrates"), [
    (0.0, 0.05, None, True),
    (2.0 * _V, 0.05, _V, False),  # at v_max, e_s > 0 pushes further: frozen
    (-2.0 * _V, 0.05, 0.0, True),  # at the lower limit 0 (forward only), e_s > 0 pulls back
], ids=["inside", "high-push", "low-pull"])
def test_distance_channel_integrates_only_when_not_pushing_into_its_limit(
        integral: float, error: float, limit: float | None, integrates: bool) -> None:
    u, before, after = _drive("s", integral, error)
    if limit is not None:
        assert u == limit
    else:
        assert 0.0 < u < _V
    k = Gains().K_is
    expected = before + k * error * _H if integrates else before
    assert after == pytest.approx(expected, rel=1e-12, abs=0.0)


@pytest.mark.parametrize(("integral", "limit", "integrates"), [
    (50.0, _V, True),  # at v_max (a large integral), e_s < 0 pulls back: integrates
    (0.0, 0.0, False),  # at the lower limit 0 (forward only), e_s < 0 pushes further: frozen
], ids=["high-pull", "low-push"])
def test_distance_channel_with_the_goal_behind_the_heading_line(
        integral: float, limit: float, integrates: bool) -> None:
    """The two cases of the distance channel the twin above cannot reach (e_s < 0)."""
    s = _stabiliser()
    s.i_s = integral
    out = s.update(0.0, 0.0, 2.5)  # alpha = beta = 0, gamma = -2.5: e_s = 100 cos(2.5) < 0
    e_s = 100.0 * math.cos(2.5)
    assert out[1] == pytest.approx(e_s, rel=1e-12)
    assert out[6] == limit
    expected = integral + Gains().K_is * e_s * _H if integrates else integral
    assert s.i_s == pytest.approx(expected, rel=1e-12, abs=0.0)


def test_angle_integral_stays_bounded_while_saturated_for_long() -> None:
    """A long saturation of the angle channel: the integral does not grow at all."""
    s = _stabiliser()
    for _ in range(2000):
        out = s.update(0.0, 0.0, -math.radians(170.0))  # far off heading: u_theta saturated
    assert out[7] == _W
    assert s.i_theta == 0.0


# -- the reference plant's own defaults (survivors of the physics mutation run) -------------


def test_the_reference_plant_at_its_defaults_is_the_exact_solution() -> None:
    """From the default start (the origin, at rest: no ``v0`` given), equal torques move the
    robot along x as the closed form says, to 1e-9: the plant's default tolerances make it a
    reference (it kills surviving mutants of the physics run: docs/testing.md)."""
    from wmr.core.physics import equal_torque_solution
    from wmr.core.plant import Pose

    params = RobotParams()
    plant = ReferencePlant()
    out = plant.reset(params, Pose(0.0, 0.0, 0.0))
    np.testing.assert_array_equal(out[:5], [0.0, 0.0, 0.0, 0.0, 0.0])
    for k in range(1, 51):
        out = plant.step(2.0, 2.0, 0.02)
        exact = equal_torque_solution(0.02 * k, 2.0, params)
        np.testing.assert_allclose(out[:5], exact[:5], rtol=0.0, atol=1e-9)


@pytest.mark.parametrize(("tau_r", "tau_l", "w_r0", "w_r1", "w_l0", "w_l1"), [
    (0.0, 2.0, 0.0, 0.0, 1.0, 3.0),  # the left wheel alone, driving
    (0.0, -2.0, 0.0, 0.0, 1.0, 3.0),  # the left wheel alone, braking
    (2.0, 0.0, 1.0, 3.0, 0.0, 0.0),  # the right wheel alone
    (1.5, -0.5, 2.0, -1.0, -0.5, 0.25),  # both, each with a sign change within the step
])
def test_step_work_is_the_trapezoid_of_each_wheels_power(
        tau_r: float, tau_l: float, w_r0: float, w_r1: float, w_l0: float,
        w_l1: float) -> None:
    """The master loop's scalar energy step, by hand: each wheel's power at both ends of the
    step, the positive part taken per wheel and per end (docs/results.md)."""
    from wmr.core.energy import step_work

    h = 0.01
    powers = [tau_r * w_r0, tau_r * w_r1, tau_l * w_l0, tau_l * w_l1]
    net, pos, absolute = step_work(h, tau_r, tau_l, w_r0, w_r1, w_l0, w_l1)
    assert net == pytest.approx(h / 2 * sum(powers), rel=1e-15, abs=0.0)
    assert pos == pytest.approx(h / 2 * sum(p for p in powers if p > 0), rel=1e-15, abs=0.0)
    assert absolute == pytest.approx(h / 2 * sum(abs(p) for p in powers), rel=1e-15, abs=0.0)

"""The paper's stabiliser (wmr.core.control.stabiliser): errors, PI, eq. 28, the singular cases."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from wmr.core.control import (
    ALIGN,
    APPROACH,
    Gains,
    Limits,
    PointStabiliser,
    unwrap_near,
    wrap_angle,
)
from wmr.infra.errors import ConfigError

finite = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False, allow_infinity=False)


@given(finite)
def test_wrap_is_in_half_open_interval(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


@given(finite, st.integers(min_value=-50, max_value=50))
def test_wrap_is_2pi_periodic(a: float, k: int) -> None:
    # equal up to the rounding of a + 2 k pi itself
    d = wrap_angle(wrap_angle(a + 2 * k * math.pi) - wrap_angle(a))
    assert abs(d) <= 1e-9


def test_wrap_edges() -> None:
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi
    assert wrap_angle(3 * math.pi) == pytest.approx(math.pi)
    assert wrap_angle(0.0) == 0.0


def test_unwrap_near_keeps_the_sign_near_pi() -> None:
    assert unwrap_near(math.pi - 0.01, -3.0) == pytest.approx(-math.pi - 0.01)
    assert unwrap_near(-math.pi + 0.01, 3.0) == pytest.approx(math.pi + 0.01)
    assert unwrap_near(1.0, -3.0) == 1.0  # far from pi: untouched
    assert unwrap_near(-math.pi + 0.01, -3.0) == pytest.approx(-math.pi + 0.01)


def _stab(goal: tuple[float, float, float] = (20.0, 10.0, 0.0), **gains: float) -> PointStabiliser:
    return PointStabiliser(*goal, Gains(**gains), Limits(), 0.15, 0.3, 0.01, 0.05)


def test_roc_errors_match_the_paper() -> None:
    s = _stab(K_ps=0.01, K_ptheta=0.01)  # small gains: outputs inside the limits
    dr, e_s, e_th, alpha, beta, gamma, u_s, u_th, _, i_s, _, i_th, w_r, w_l, *_ = \
        s.update(0.0, 0.0, 0.1)
    assert dr == pytest.approx(math.hypot(20, 10))  # eq. 26
    assert alpha == pytest.approx(math.atan2(10, 20))  # eq. 27, corrected
    assert beta == pytest.approx(0.0 - alpha)  # beta = theta_d - alpha
    assert gamma == pytest.approx(2 * alpha - 0.0 - 0.1)  # gamma = 2 alpha - theta_d - theta
    assert e_s == pytest.approx(dr * math.cos(gamma))
    assert e_th == gamma
    assert u_s == pytest.approx(0.01 * e_s)  # eq. 29, integral still zero
    assert (i_s, i_th) == (0.0, 0.0)
    assert w_r == pytest.approx((u_s + 0.3 * u_th) / 0.15)  # eq. 28 as rates
    assert w_l == pytest.approx((u_s - 0.3 * u_th) / 0.15)
    # the integral of eq. 29 accumulates K_i e h
    out = s.update(0.0, 0.0, 0.1)
    assert out[9] == pytest.approx(Gains().K_is * e_s * 0.01)


def test_gamma_is_wrapped() -> None:
    s = _stab(goal=(-10.0, -0.001, 0.0))
    *_, gamma = s.update(0.0, 0.0, 0.0)[:6]
    assert -math.pi - 0.31 < gamma < math.pi + 0.31


def test_goal_behind_turns_in_place_without_chattering() -> None:
    """gamma near +-pi: the turn direction is held (hysteresis), u_s = 0 (forward only)."""
    s = _stab(goal=(-10.0, 0.0, math.pi))
    signs = []
    for k in range(20):
        eps = 1e-3 * (-1) ** k  # heading jitters around 0: raw gamma flips between +-pi
        out = s.update(0.0, 0.0, eps)
        assert out[6] == 0.0  # u_s
        signs.append(math.copysign(1.0, out[7]))
    assert len(set(signs)) == 1


def test_beta_is_clamped_for_goal_poses_facing_the_robot() -> None:
    s = _stab(goal=(10.0, 0.0, math.pi))  # beta = pi: the paper's law would drive away
    out = s.update(0.0, 0.0, 0.0)
    gamma = out[5]
    assert abs(gamma) == pytest.approx(math.pi / 3)  # turn towards the spiral bearing


def test_alignment_inside_stop_radius() -> None:
    s = _stab(goal=(0.01, 0.0, math.pi / 2))
    out = s.update(0.0, 0.0, 0.0)
    assert s.phase == ALIGN
    assert out[2] == pytest.approx(math.pi / 2)  # e_theta = theta_d - theta
    assert out[7] > 0.0
    assert abs(out[6]) < 0.01  # only the small position hold
    assert s.converged(0.0, 0.0, math.pi / 2, 0.0, 0.0, 0.01)
    assert not s.converged(0.0, 0.0, 0.0, 0.0, 0.0, 0.01)
    # pushed out of 2 epsilon: back to the approach
    s.update(-0.2, 0.0, 0.0)
    assert s.phase == APPROACH


def test_outputs_respect_the_limits() -> None:
    lim = Limits()
    s = _stab()
    for theta in (0.0, 1.0, -2.0, 3.1):
        out = s.update(0.0, 0.0, theta)
        assert 0.0 <= out[6] <= lim.v_max_mps
        assert abs(out[7]) <= lim.omega_max_radps
        assert abs(out[12]) <= lim.wheel_speed_max_radps + 1e-12
        assert abs(out[13]) <= lim.wheel_speed_max_radps + 1e-12


def test_anti_windup_freezes_the_integral_in_saturation() -> None:
    s = _stab()
    for _ in range(1000):
        out = s.update(0.0, 0.0, 0.0)
    assert out[6] == Limits().v_max_mps
    assert out[9] == 0.0  # e_s > 0 and u_s saturated high: no integration


def test_wheel_limit_scales_both_wheels_and_keeps_the_curvature() -> None:
    s = PointStabiliser(20.0, 10.0, 0.0, Gains(), Limits(wheel_speed_max_radps=2.0),
                        0.15, 0.3, 0.01, 0.05)
    out = s.update(0.0, 0.0, 0.3)
    w_r, w_l = out[12], out[13]
    assert max(abs(w_r), abs(w_l)) == pytest.approx(2.0)
    u_s, u_th = out[6], out[7]
    assert (w_r - w_l) / (w_r + w_l) == pytest.approx(0.3 * u_th / u_s)


def test_bad_gains_and_limits_name_the_field() -> None:
    with pytest.raises(ConfigError, match=r"gains\.K_ps"):
        Gains(K_ps=math.nan)
    with pytest.raises(ConfigError, match=r"limits\.torque_max_nm"):
        Limits(torque_max_nm=0.0)
    with pytest.raises(ConfigError, match=r"gains\.K_is"):
        Gains(K_is=-1.0)

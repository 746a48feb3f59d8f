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
from wmr.core.control.stabiliser import (
    HYSTERESIS_BAND_RAD,
    OMEGA_REST_RADPS,
    V_REST_MPS,
    _wrapped_near,
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


# -- the rules below were each broken by a surviving mutant (docs/testing.md) ------------------

_BAND = HYSTERESIS_BAND_RAD
_IN_HI, _IN_LO = math.pi - 0.1, -math.pi + 0.1  # inside the band near +pi and near -pi


def test_unwrap_near_shifts_only_inside_the_band_and_only_against_the_previous_sign() -> None:
    """The rule of its docstring, case by case: a previous of the same sign or zero (the first
    step of a run has no sign) leaves the angle alone; the other sign, however small, shifts
    it by 2 pi towards it; far from +-pi nothing moves; and the band's edges lie outside the
    band, so that the result stays in the open interval (-pi - b, pi + b)."""
    for previous in (0.0, 0.5, 3.0):
        assert unwrap_near(_IN_HI, previous) == _IN_HI
    for previous in (0.0, -0.5, -3.0):
        assert unwrap_near(_IN_LO, previous) == _IN_LO
    for previous in (-0.5, -3.0):
        assert unwrap_near(_IN_HI, previous) == _IN_HI - 2 * math.pi
    for previous in (0.5, 3.0):
        assert unwrap_near(_IN_LO, previous) == _IN_LO + 2 * math.pi
    for previous in (-3.0, -0.5, 0.0, 0.5, 3.0):
        for far in (1.0, -1.0, 0.0, math.pi - _BAND - 0.01, _BAND - math.pi + 0.01):
            assert unwrap_near(far, previous) == far
    for edge, previous in ((math.pi - _BAND, -1.0), (_BAND - math.pi, 1.0)):
        out = unwrap_near(edge, previous)
        assert out == edge
        assert -math.pi - _BAND < out < math.pi + _BAND


def test_the_hot_path_wraps_and_unwraps_as_the_two_functions_do() -> None:
    """``_wrapped_near(a, p)`` is ``unwrap_near(wrap_angle(a), p)``, bit for bit, on the
    multiples of pi/4 (-pi itself included), the band's edges and points either side."""
    angles = [k * math.pi / 4 + d for k in range(-12, 13) for d in (0.0, 1e-9, -1e-9, 0.05)]
    angles += [math.pi - _BAND, _BAND - math.pi, _IN_HI, _IN_LO, -math.pi, math.pi]
    for a in angles:
        for previous in (-3.0, -0.5, 0.0, 0.5, 3.0):
            assert _wrapped_near(a, previous) == unwrap_near(wrap_angle(a), previous), (a, previous)


def _state(s: PointStabiliser) -> dict[str, object]:
    return {name: getattr(s, name) for name in PointStabiliser.__slots__}


def test_reset_is_a_fresh_stabiliser() -> None:
    fresh = _stab(goal=(0.0, 0.0, 0.0))
    used = _stab(goal=(0.0, 0.0, 0.0))
    used.update(-1.0, 0.0, -0.5)  # approach: integrals and hysteresis memories set
    used.update(-1.0, 0.02, -0.5)
    assert used.i_s != 0.0 and used.i_theta != 0.0
    assert used.prev_gamma != 0.0 and used.prev_beta != 0.0
    used.update(0.0, 0.0, 0.3)  # on the goal: alignment
    assert used.phase == ALIGN
    used.reset()
    assert _state(used) == _state(fresh)
    assert _state(fresh) | {"phase": APPROACH, "i_s": 0.0, "i_theta": 0.0, "prev_gamma": 0.0,
                            "prev_beta": 0.0} == _state(fresh)


def _foot_of_perpendicular_is(out: tuple[float, ...], point: tuple[float, float],
                              pose: tuple[float, float, float]) -> None:
    """D = B + e_s (cos theta, sin theta) is the foot of the perpendicular from ``point`` on
    the heading line: D - B along the heading, ``point`` - D across it (Fig. 4)."""
    x, y, theta = pose
    hx, hy = math.cos(theta), math.sin(theta)
    d_x, d_y = out[14], out[15]
    assert (d_x - x) * hy - (d_y - y) * hx == pytest.approx(0.0, abs=1e-12)
    assert (point[0] - d_x) * hx + (point[1] - d_y) * hy == pytest.approx(0.0, abs=1e-12)


def test_phases_change_at_the_documented_radii_and_start_afresh() -> None:
    """docs/control.md: alignment when dr <= eps/2, back to the approach only when pushed out
    of 2 eps; each phase starts with zero integrals and no hysteresis memory; the alignment is
    P only and holds B at the goal along the heading line."""
    eps = 0.05
    s = _stab(goal=(0.0, 0.0, 0.0))
    for _ in range(3):
        out = s.update(-1.0, 0.0, -0.5)  # approach, gamma = +0.5
    assert s.phase == APPROACH and out[5] == pytest.approx(0.5)
    assert out[9] != 0.0 and out[11] != 0.0  # the integrals ran
    # exactly eps/2 away, heading error theta_d - theta just inside the band near -pi: the
    # alignment starts with no memory of the approach's positive gamma
    out = s.update(-0.5 * eps, 0.0, _IN_HI)
    assert s.phase == ALIGN
    assert out[5] == pytest.approx(_IN_LO) and out[2] == out[5]
    assert (out[9], out[11]) == (0.0, 0.0)
    # the alignment error keeps its sign near +-pi as gamma does (docs/control.md)
    out = s.update(-0.5 * eps, 0.0, _IN_LO)  # theta_d - theta = pi - 0.1, wrapped
    assert out[5] == pytest.approx(_IN_LO - 0.2)
    pose = (-0.012, 0.016, 0.5 * math.pi - 0.3)
    for _ in range(3):
        out = s.update(*pose)
        assert (out[9], out[11], s.i_s, s.i_theta) == (0.0, 0.0, 0.0, 0.0)  # P only
    assert out[5] == pytest.approx(0.3 - 0.5 * math.pi)
    _foot_of_perpendicular_is(out, (0.0, 0.0), pose)
    assert out[1] == pytest.approx(0.012 * math.cos(pose[2]) - 0.016 * math.sin(pose[2]))
    out = s.update(-2.0 * eps, 0.0, -0.5)  # on the exit radius: still aligning (gamma 0.5)
    assert s.phase == ALIGN and out[5] == pytest.approx(0.5)
    # pushed out to 2.5 eps, gamma just inside the band near -pi: a fresh approach
    out = s.update(-2.5 * eps, 0.0, _IN_HI)
    assert s.phase == APPROACH
    assert out[5] == pytest.approx(_IN_LO)
    assert (out[9], out[11]) == (0.0, 0.0)


@pytest.mark.parametrize(("goal_heading", "bearing"), [
    (0.4, -0.4),  # |beta| < beta_max: R is the goal rotated by -beta about B
    (2.0, -math.pi / 3),  # beta clamped to +beta_max
    (-2.0, math.pi / 3),  # beta clamped to -beta_max
])
def test_the_reference_point_is_the_goal_rotated_by_the_clamped_beta(
        goal_heading: float, bearing: float) -> None:
    """Fig. 6: R lies at the goal's distance from B, at the bearing alpha - beta_c; D is the
    foot of the perpendicular from R on the heading line."""
    b = (2.0, 1.0, 0.7)
    s = _stab(goal=(3.0, 1.0, goal_heading))  # alpha = 0, dr = 1
    out = s.update(*b)
    assert (out[16], out[17]) == pytest.approx((2.0 + math.cos(bearing), 1.0 + math.sin(bearing)),
                                               abs=1e-12)
    _foot_of_perpendicular_is(out, (out[16], out[17]), b)


def test_beta_keeps_its_sign_near_pi() -> None:
    """The goal straight behind, B jittering across the line: beta = theta_d - alpha crosses
    +-pi each step, and the hysteresis keeps its sign (the same rule as gamma's)."""
    s = _stab(goal=(-10.0, 0.0, 0.0))
    betas = [s.update(0.0, 0.01 * (-1) ** k, math.pi)[4] for k in range(6)]
    # the first from a previous of zero: the wrapped value; then pi -+ 0.001, never -pi + ...
    assert betas == pytest.approx([math.pi - 0.001 * (-1) ** k for k in range(6)], abs=1e-6)


def test_wheel_limit_scales_a_right_turn_too() -> None:
    """The mirror of the test above: the left wheel is the faster one."""
    s = PointStabiliser(20.0, -10.0, 0.0, Gains(), Limits(wheel_speed_max_radps=2.0),
                        0.15, 0.3, 0.01, 0.05)
    out = s.update(0.0, 0.0, -0.3)
    w_r, w_l = out[12], out[13]
    assert abs(w_l) > abs(w_r)
    assert abs(w_l) == pytest.approx(2.0)


def test_heading_error_is_theta_minus_theta_d_wrapped() -> None:
    s = _stab(goal=(0.0, 0.0, 0.2))
    assert s.heading_error(0.5) == pytest.approx(0.3)
    assert s.heading_error(0.2 + math.pi + 0.1) == pytest.approx(-math.pi + 0.1)


def test_converged_is_each_documented_bound_inclusive_and_both_coordinates() -> None:
    """docs/control.md: dr <= eps, |theta - theta_d| <= tolerance, |v| <= 0.01 m/s,
    |omega| <= 0.02 rad/s, in the alignment phase; dr counts both coordinates."""
    eps, tol = 0.05, 0.01
    s = _stab(goal=(0.0, 0.0, 0.0))
    s.update(0.0, 0.0, 0.0)
    assert s.phase == ALIGN
    assert s.converged(-eps, 0.0, tol, V_REST_MPS, -OMEGA_REST_RADPS, tol)
    assert s.converged(0.0, eps, -tol, -V_REST_MPS, OMEGA_REST_RADPS, tol)
    assert not s.converged(1.2 * eps, 0.0, 0.0, 0.0, 0.0, tol)
    assert not s.converged(0.0, 1.2 * eps, 0.0, 0.0, 0.0, tol)


def test_a_bad_gain_or_limit_is_one_line_with_the_problem_and_the_fix() -> None:
    cases: list[tuple[dict[str, object], type[Gains] | type[Limits], str]] = [
        ({"K_ps": math.nan}, Gains, "gains.K_ps: must be a finite number, got nan"),
        ({"K_ps": True}, Gains, "gains.K_ps: must be a finite number, got True"),
        ({"K_ps": "1"}, Gains, "gains.K_ps: must be a finite number, got '1'"),
        ({"K_is": -1.0}, Gains, "gains.K_is: must be >= 0, got -1.0"),
        ({"torque_max_nm": 0.0}, Limits, "limits.torque_max_nm: must be > 0, got 0.0"),
    ]
    for kwargs, section, problem in cases:
        with pytest.raises(ConfigError) as err:
            section(**kwargs)  # type: ignore[arg-type]
        line = str(err.value)
        assert "\n" not in line
        fix = ("give a real number" if "finite" in problem
               else "use a non-negative gain or a positive limit")
        assert line == f"{problem} ({fix})", line
    # zero gains are allowed (a P-only or I-only loop); only the limits must be positive
    assert Gains(K_is=0.0, K_itheta=0.0).K_is == 0.0


def test_gains_and_limits_round_trip_through_their_dicts_as_floats() -> None:
    g = Gains(K_ps=1, K_is=0.5, K_ptheta=3, K_itheta=0.25, K_pw=9, K_iw=30)
    lim = Limits(v_max_mps=2, omega_max_radps=1.0, wheel_speed_max_radps=12, torque_max_nm=5)
    for obj in (g, lim):
        d = obj.as_dict()
        assert all(type(v) is float for v in d.values())
        assert type(obj)(**d) == obj

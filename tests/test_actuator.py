"""Wheel speed servo (wmr.core.control.actuator)."""

from __future__ import annotations

import math

import pytest

from wmr.core.control import WheelServo


def _inertia_response(servo: WheelServo, ref: float, j: float, n: int) -> list[float]:
    w = 0.0
    out = []
    for _ in range(n):
        tau = servo.update(ref, w)
        w += tau / j * servo.h  # inertia under zero-order hold
        out.append(w)
    return out


def test_tracks_a_step_on_the_effective_wheel_inertia() -> None:
    servo = WheelServo(7.0, 28.0, 8.0, 0.01)
    w = _inertia_response(servo, 2.0, 0.35, 300)
    assert w[-1] == pytest.approx(2.0, abs=1e-3)
    assert max(w) < 2.0 * 1.15  # modest overshoot


def test_torque_saturates() -> None:
    servo = WheelServo(7.0, 28.0, 8.0, 0.01)
    assert servo.update(100.0, 0.0) == 8.0
    assert servo.update(-100.0, 0.0) == -8.0


def test_back_calculation_limits_windup() -> None:
    """A long saturated step: without anti-windup the overshoot would be large."""
    servo = WheelServo(7.0, 28.0, 8.0, 0.01)
    w = _inertia_response(servo, 10.0, 0.35, 600)
    assert w[-1] == pytest.approx(10.0, abs=1e-2)
    assert max(w) < 10.0 * 1.05
    naive = WheelServo(7.0, 28.0, 8.0, 0.01)
    naive.k_t = 0.0  # no back-calculation
    w2 = _inertia_response(naive, 10.0, 0.35, 600)
    assert max(w2) > max(w) + 0.5


def test_friction_feed_forward() -> None:
    servo = WheelServo(0.0, 0.0, 8.0, 0.01, b_ff=0.1, tau_c_ff=0.5, w_c=0.01)
    assert servo.update(2.0, 2.0) == pytest.approx(0.1 * 2.0 + 0.5, rel=1e-6)


# -- each rule below was broken by a surviving mutant (docs/testing.md) ------------------------

_H = 0.01


def test_no_feed_forward_unless_given_and_the_default_smoothing_speed() -> None:
    """No friction, no feed-forward: zero gains and zero error give zero torque; the Coulomb
    term alone smooths over the default 0.01 rad/s of docs/model.md (76 % of tau_c at w_c)."""
    assert WheelServo(0.0, 0.0, 8.0, _H).update(2.0, 2.0) == 0.0
    servo = WheelServo(0.0, 0.0, 8.0, _H, tau_c_ff=0.5)
    assert servo.update(0.01, 0.01) == pytest.approx(0.5 * math.tanh(1.0), rel=1e-12)


@pytest.mark.parametrize("omega_ref", [0.005, -0.02, 3.0])
def test_friction_feed_forward_inside_and_outside_the_smoothing(omega_ref: float) -> None:
    """b_ff omega + tau_c tanh(omega / w_c), with tau_c = 1 N m (a round value too)."""
    servo = WheelServo(0.0, 0.0, 8.0, _H, b_ff=0.1, tau_c_ff=1.0, w_c=0.01)
    expected = 0.1 * omega_ref + 1.0 * math.tanh(omega_ref / 0.01)
    assert servo.update(omega_ref, omega_ref) == pytest.approx(expected, rel=1e-12)


def _integral_after_one_saturated_step(K_p: float, K_i: float, period_s: float) -> float:
    servo = WheelServo(K_p, K_i, 8.0, period_s)
    assert servo.update(20.0, 0.0) == 8.0
    return servo.integral


@pytest.mark.parametrize(("K_p", "K_i", "period_s", "h_over_T_t"), [
    (7.0, 28.0, 0.01, 0.1),  # the paper's robot: T_t = 0.4 * 7 / 28 = 0.1 s, ten periods
    (0.5, 2.0, 0.01, 0.1),  # T_t = 0.1 s again, with K_p < 1
    (7.0, 28.0, 0.5, 1.0),  # h / T_t = 5: capped at 1
])
def test_back_calculation_gain_is_h_over_0_4_T_i_capped_at_1(
        K_p: float, K_i: float, period_s: float, h_over_T_t: float) -> None:
    """The module doc's rule: I += K_i h e + (h / T_t)(tau - v), T_t = 0.4 K_p / K_i, the
    gain capped at 1; the first step of a 20 rad/s step from rest saturates at 8 N m."""
    e, v = 20.0, K_p * 20.0
    expected = K_i * period_s * e + h_over_T_t * (8.0 - v)
    assert _integral_after_one_saturated_step(K_p, K_i, period_s) == pytest.approx(
        expected, rel=1e-12)


def test_an_integral_only_servo_back_calculates_at_full_gain() -> None:
    """K_p = 0: T_t = 0 and the gain is 1: the integral stops where the torque saturates."""
    servo = WheelServo(0.0, 28.0, 8.0, _H)
    for _ in range(3):
        servo.update(10.0, 0.0)  # the integral grows 2.8 a step: 8.4 > 8 after three
    assert servo.integral == pytest.approx(8.4)
    assert servo.update(10.0, 0.0) == 8.0
    assert servo.integral == pytest.approx(8.4 + 2.8 + 1.0 * (8.0 - 8.4))


def test_reset_is_a_fresh_servo() -> None:
    fresh = WheelServo(7.0, 28.0, 8.0, _H)
    used = WheelServo(7.0, 28.0, 8.0, _H)
    for _ in range(5):
        used.update(3.0, 0.0)
    assert used.integral != 0.0
    used.reset()
    assert [used.update(1.0, 0.2) for _ in range(3)] == [fresh.update(1.0, 0.2)
                                                          for _ in range(3)]

"""Wheel speed servo (wmr.core.control.actuator)."""

from __future__ import annotations

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

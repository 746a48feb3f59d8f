"""The hand-written physics (wmr.core.physics): conservation laws, exact solutions, derivation."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from wmr.core.physics import (
    ReferencePlant,
    accelerations,
    derivatives,
    equal_torque_solution,
    kinetic_energy,
    mass_matrix_diag,
    outputs,
    spin_solution,
    wheel_speeds,
)
from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams

P = RobotParams()


def _integrate(rhs, y0, t_end, n_eval=50):  # type: ignore[no-untyped-def]
    return solve_ivp(rhs, (0.0, t_end), y0, method="DOP853", rtol=1e-11, atol=1e-12,
                     t_eval=np.linspace(0.0, t_end, n_eval))


def _printed_eq24_derivatives(state, tau_r, tau_l, p):  # type: ignore[no-untyped-def]
    """The paper's eq. 24 as printed: 2 Iwm / r^2 in row 1, column 2 of M_wm, m in (1, 1)."""
    _, th, v, w = state[:4]
    m_wm = np.array([[p.m, 2 * p.Iwm / p.r**2],
                     [0.0, p.Ig + p.m * p.l**2 + 2 * p.L**2 * p.Iwm / p.r**2]])
    c = np.array([-p.m * p.l * w**2, p.m * p.l * v * w])
    b = np.array([[1 / p.r, 1 / p.r], [p.L / p.r, -p.L / p.r]])
    acc = np.linalg.solve(m_wm, b @ np.array([tau_r, tau_l]) - c)
    return [v * math.cos(th), w, acc[0], acc[1]]


def test_outputs_order_and_values() -> None:
    s = [1.0, 2.0, 0.5, 0.3, -0.2, 4.0, 5.0]
    out = outputs(s, P)
    assert out.shape == (len(OUTPUT_NAMES),)
    named = dict(zip(OUTPUT_NAMES, out, strict=True))
    w_r, w_l = wheel_speeds(0.3, -0.2, P)
    assert named["omega_r"] == pytest.approx(w_r)
    assert named["omega_l"] == pytest.approx(w_l)
    assert named["x_G"] == pytest.approx(1.0 + P.l * math.cos(0.5))  # eq. 4
    assert named["y_G"] == pytest.approx(2.0 + P.l * math.sin(0.5))
    # E_kin as the FMU writes it: platform about G, wheels about their axles
    e_fmu = 0.5 * (P.m * (0.3**2 + (P.l * 0.2) ** 2) + P.Ig * 0.2**2
                   + P.Iwm * (w_r**2 + w_l**2))
    assert named["E_kin"] == pytest.approx(e_fmu, rel=1e-12)


def test_energy_conserved_with_zero_torque_while_v_and_omega_exchange() -> None:
    y0 = [0.0, 0.0, 0.0, 0.0, 1.5, 0.0, 0.0]  # pure spin at t = 0
    sol = _integrate(lambda t, s: derivatives(s, 0.0, 0.0, P), y0, 5.0)
    e = [kinetic_energy(v, w, P) for v, w in zip(sol.y[3], sol.y[4], strict=True)]
    assert max(abs(x - e[0]) for x in e) / e[0] < 1e-9
    # the centrifugal m l omega^2 pushes B forward: v changes, omega gives up energy
    assert sol.y[3, -1] > 0.1
    assert sol.y[4, -1] < 1.5 - 0.1


def test_printed_eq24_breaks_energy_conservation() -> None:
    """The test that would fail on the printed eq. 24 (errata): its energy drifts."""
    y0 = [0.0, 0.0, 0.0, 1.5]  # x, theta, v, omega
    sol = _integrate(lambda t, s: _printed_eq24_derivatives(s, 0.0, 0.0, P), y0, 5.0)
    e = [kinetic_energy(v, w, P) for v, w in zip(sol.y[2], sol.y[3], strict=True)]
    drift = max(abs(x - e[0]) for x in e) / e[0]
    assert drift > 1e-3, "the printed eq. 24 would have to conserve energy to pass"
    # ... while the corrected form, same start, conserves it to the solver's tolerance
    sol2 = _integrate(lambda t, s: derivatives(s, 0.0, 0.0, P), [0, 0, 0, 0, 1.5, 0, 0], 5.0)
    e2 = [kinetic_energy(v, w, P) for v, w in zip(sol2.y[3], sol2.y[4], strict=True)]
    assert max(abs(x - e2[0]) for x in e2) / e2[0] < 1e-9


@pytest.mark.parametrize("heading", [0.0, 0.7, -2.5])
def test_equal_torques_from_rest_match_the_analytic_solution(heading: float) -> None:
    tau = 2.5
    start = Pose(1.0, -2.0, heading)
    y0 = [start.x_m, start.y_m, heading, 0.0, 0.0, 0.0, 0.0]
    sol = _integrate(lambda t, s: derivatives(s, tau, tau, P), y0, 3.0, n_eval=7)
    for k, t in enumerate(sol.t):
        np.testing.assert_allclose(sol.y[:, k], equal_torque_solution(t, tau, P, start),
                                   rtol=1e-9, atol=1e-10)
    m11, _ = mass_matrix_diag(P)
    assert sol.y[3, -1] == pytest.approx(2 * tau * 3.0 / (P.r * (P.m + 2 * P.Iwm / P.r**2)))
    assert m11 == pytest.approx(P.m + 2 * P.Iwm / P.r**2)


def test_pure_spin_is_exact_only_with_l_zero() -> None:
    tau = 1.0
    p0 = replace(P, l=0.0)
    sol = _integrate(lambda t, s: derivatives(s, tau, -tau, p0), [0.0] * 7, 2.0, n_eval=5)
    for k, t in enumerate(sol.t):
        v, w = spin_solution(t, tau, p0)
        assert v == 0.0
        assert sol.y[3, k] == pytest.approx(0.0, abs=1e-12)
        assert sol.y[4, k] == pytest.approx(w, rel=1e-9, abs=1e-12)
    # l != 0: v does not stay zero; the leading Taylor terms hold for small t
    t = 0.05
    sol = _integrate(lambda _t, s: derivatives(s, tau, -tau, P), [0.0] * 7, t, n_eval=2)
    v_a, w_a = spin_solution(t, tau, P)
    assert sol.y[3, -1] > 0.0
    assert sol.y[3, -1] == pytest.approx(v_a, rel=1e-3)
    assert sol.y[4, -1] == pytest.approx(w_a, rel=1e-4)


def test_power_balance_with_torques_and_friction() -> None:
    """dT/dt = tau_r omega_r + tau_l omega_l - tau_fr omega_r - tau_fl omega_l along a run."""
    p = replace(P, b_f=0.05, tau_c=0.3, w_c=0.5)
    torques = (3.0, -1.0)

    def rhs(t: float, s: np.ndarray) -> list[float]:
        d = derivatives(s[:7], *torques, p)
        w_r, w_l = wheel_speeds(s[3], s[4], p)
        work = sum(tq * w for tq, w in zip(torques, (w_r, w_l), strict=True))
        loss = sum((p.b_f * w + p.tau_c * math.tanh(w / p.w_c)) * w for w in (w_r, w_l))
        return [*d, work - loss]

    sol = _integrate(rhs, [0, 0, 0, 0.2, -0.3, 0, 0, 0.0], 4.0)
    t_kin = np.array([kinetic_energy(v, w, p) for v, w in zip(sol.y[3], sol.y[4], strict=True)])
    np.testing.assert_allclose(t_kin - t_kin[0], sol.y[7], atol=1e-8)


def _lagrangian(q: np.ndarray, qd: np.ndarray, p: RobotParams) -> float:
    """T of platform (about G), wheels and rotors in q = (x, y, theta, phi_r, phi_l)."""
    _, _, th, _, _ = q
    xd, yd, thd, prd, pld = qd
    vgx = xd - p.l * math.sin(th) * thd  # eq. 9
    vgy = yd + p.l * math.cos(th) * thd
    return 0.5 * (p.m * (vgx**2 + vgy**2) + p.Ig * thd**2 + p.Iwm * (prd**2 + pld**2))


def test_eqs_18_to_24_follow_from_the_lagrangian_with_the_nonholonomic_constraint() -> None:
    """Lagrange-d'Alembert, by finite differences: S^T (d/dt dL/dqd - dL/dq - Q) = 0.

    qd = S(q) eta with eta = (v, omega) encodes rolling without slip and no side slip
    (eq. 10); projecting on S removes the constraint forces.  The accelerations solved from it
    must equal :func:`wmr.core.physics.derivatives`.
    """
    p = replace(P, b_f=0.1, tau_c=0.2, w_c=0.3)
    rng = np.random.default_rng(1)
    hq = 1e-4
    for _ in range(5):
        th = rng.uniform(-math.pi, math.pi)
        v, w = rng.uniform(-1, 1, size=2)
        tau_r, tau_l = rng.uniform(-5, 5, size=2)
        q = np.array([0.3, -0.2, th, 0.1, 0.4])

        def s_of(q: np.ndarray) -> np.ndarray:
            c, s = math.cos(q[2]), math.sin(q[2])
            return np.array([[c, 0], [s, 0], [0, 1], [1 / p.r, p.L / p.r], [1 / p.r, -p.L / p.r]])

        S = s_of(q)
        eta = np.array([v, w])
        qd = S @ eta
        n = 5
        # mass matrix d2L/dqd2 (L is quadratic in qd: central differences are exact)
        M = np.zeros((n, n))
        for i in range(n):
            for j in range(n):
                ei, ej = np.eye(n)[i] * hq, np.eye(n)[j] * hq
                M[i, j] = (_lagrangian(q, qd + ei + ej, p) - _lagrangian(q, qd + ei - ej, p)
                           - _lagrangian(q, qd - ei + ej, p)
                           + _lagrangian(q, qd - ei - ej, p)) / (4 * hq * hq)
        # d/dq of dL/dqd, times qd; and dL/dq
        def dl_dqd(qq: np.ndarray, qd: np.ndarray = qd) -> np.ndarray:
            return np.array([(_lagrangian(qq, qd + e, p) - _lagrangian(qq, qd - e, p)) / (2 * hq)
                             for e in np.eye(5) * hq])

        mixed = np.zeros(n)
        dl_dq = np.zeros(n)
        for j in range(n):
            ej = np.eye(n)[j] * hq
            mixed += (dl_dqd(q + ej) - dl_dqd(q - ej)) / (2 * hq) * qd[j]
            dl_dq[j] = (_lagrangian(q + ej, qd, p) - _lagrangian(q - ej, qd, p)) / (2 * hq)
        # S dot eta: derivative of S along qd
        s_dot = (s_of(q + qd * hq) - s_of(q - qd * hq)) / (2 * hq)
        w_r, w_l = wheel_speeds(v, w, p)
        Q = np.array([0, 0, 0,
                      tau_r - p.b_f * w_r - p.tau_c * math.tanh(w_r / p.w_c),
                      tau_l - p.b_f * w_l - p.tau_c * math.tanh(w_l / p.w_c)])
        # S^T M (S eta_dot + S_dot eta) + S^T (mixed - dL/dq) = S^T Q
        lhs = S.T @ M @ S
        rhs = S.T @ (Q - M @ (s_dot @ eta) - mixed + dl_dq)
        eta_dot = np.linalg.solve(lhs, rhs)
        d = derivatives([0.3, -0.2, th, v, w, 0.1, 0.4], tau_r, tau_l, p)
        np.testing.assert_allclose(eta_dot, d[3:5], rtol=1e-6, atol=1e-7)
        # and the mass matrix it implies is the corrected, diagonal eq. 24
        np.testing.assert_allclose(lhs, np.diag(mass_matrix_diag(p)), rtol=1e-5, atol=1e-5)


def test_reference_plant_protocol() -> None:
    plant = ReferencePlant()
    out0 = plant.reset(P, Pose(1.0, 2.0, 0.5), v0_mps=0.2)
    assert out0[0] == 1.0 and out0[3] == pytest.approx(0.2)
    out = plant.step(1.0, 1.0, 0.01)
    assert out.shape == (len(OUTPUT_NAMES),)
    assert out[3] > 0.2
    with pytest.raises(ValueError, match=r"non-finite torque input \(nan, 0\.0\)"):
        plant.step(math.nan, 0.0, 0.01)
    plant.close()


def test_the_reference_plant_at_its_default_tolerances_is_a_reference() -> None:
    """One long step (2 s) of a free nonlinear motion, where the tolerances decide the
    accuracy (the 10 ms steps of a run are exact at any tolerance): with its defaults the
    plant conserves the kinetic energy and meets a tighter solution of the same ODE."""
    plant = ReferencePlant()
    plant.reset(P, Pose(0.0, 0.0, 0.3), v0_mps=0.8, omega0_radps=2.0)
    out = plant.step(0.0, 0.0, 2.0)
    state = plant.state
    e0 = kinetic_energy(0.8, 2.0, P)
    assert kinetic_energy(state[3], state[4], P) == pytest.approx(e0, rel=1e-9)
    tight = _integrate(lambda _t, s: derivatives(s, 0.0, 0.0, P),
                       [0.0, 0.0, 0.3, 0.8, 2.0, 0.0, 0.0], 2.0, n_eval=2)
    np.testing.assert_allclose(state, tight.y[:, -1], rtol=0.0, atol=1e-8)
    assert plant.t == 2.0
    np.testing.assert_array_equal(out, outputs(state, P))
    plant.step(0.0, 0.0, 0.5)
    assert plant.t == 2.5  # the clock accumulates the steps


def test_a_fresh_reference_plant_is_one_reset_to_the_defaults() -> None:
    """Before its first reset the plant is the default robot at rest at the origin, at t = 0."""
    fresh, reset = ReferencePlant(), ReferencePlant()
    reset.reset(RobotParams(), Pose(0.0, 0.0, 0.0))
    assert fresh.params == reset.params == RobotParams()
    assert fresh.t == reset.t == 0.0
    np.testing.assert_array_equal(fresh.state, reset.state)
    assert fresh.state.shape == (7,)


@pytest.mark.parametrize("tau", [2.5, -0.4])
def test_pure_spin_with_l_zero_is_linear_in_the_torque(tau: float) -> None:
    """omega(t) = c t / M22 with c = 2 L tau / r, for torques other than 1 N m."""
    p0 = replace(P, l=0.0)
    sol = _integrate(lambda _t, s: derivatives(s, tau, -tau, p0), [0.0] * 7, 1.0, n_eval=3)
    for k, t in enumerate(sol.t):
        assert spin_solution(t, tau, p0)[1] == pytest.approx(sol.y[4, k], rel=1e-9, abs=1e-12)


def test_eq24_and_the_kinematics_at_one_state_by_hand() -> None:
    """Eq. 23 with the corrected eq. 24 and eq. 7, 3 at one state, each term worked out by
    hand with round numbers (no friction): M11 = 2 + 2(0.125)/0.25 = 3,
    M22 = 1 + 2(0.25) + 2(1)(0.125)/0.25 = 2.5; at v = 1 m/s, omega = 2 rad/s, tau = (3, 1):
    v' = ((3 + 1)/0.5 + 2(0.5)(4))/3 = 4, omega' = ((1)(3 - 1)/0.5 - 2(0.5)(1)(2))/2.5 = 0.8,
    the wheels (1 + 2)/0.5 = 6 and (1 - 2)/0.5 = -2 rad/s.  A direct check, so that a wrong
    term fails here at once rather than by a trajectory that no longer converges."""
    params = RobotParams(m=2.0, r=0.5, L=1.0, l=0.5, Ig=1.0, Iwm=0.125, b_f=0.0, tau_c=0.0)
    assert accelerations(1.0, 2.0, 3.0, 1.0, params) == pytest.approx((4.0, 0.8), abs=1e-12)
    theta = math.pi / 6
    state = np.array([0.3, -0.2, theta, 1.0, 2.0, 7.0, -5.0])  # phi_r, phi_l: any angles
    assert derivatives(state, 3.0, 1.0, params) == pytest.approx(
        [math.sqrt(3) / 2, 0.5, 2.0, 4.0, 0.8, 6.0, -2.0], abs=1e-12)

"""The FMU against independent facts: conservation, analytic solutions, a second implementation.

Each test here would fail on the paper's printed equations (errata.md): a wrong eq. 24 breaks
the energy balance, a wrong eq. 19 turns the pure spin into a drive, a wrong eq. 16 makes the
robot accelerate with no torque.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams
from wmr.infra.errors import FmuError

IDX = {n: i for i, n in enumerate(OUTPUT_NAMES)}
P = RobotParams()
M11 = P.m + 2 * P.Iwm / P.r**2
M22 = P.Ig + P.m * P.l**2 + 2 * P.L**2 * P.Iwm / P.r**2


def _run(plant: FmuPlant, torques: list[tuple[float, float]], h: float,
         params: RobotParams = P, start: Pose | None = None, v0: float = 0.0,
         omega0: float = 0.0) -> np.ndarray:
    rows = [plant.reset(params, start or Pose(0, 0, 0), v0, omega0).copy()]
    for tau_r, tau_l in torques:
        rows.append(plant.step(tau_r, tau_l, h).copy())
    return np.array(rows)


def test_energy_is_conserved_with_zero_torque(plant: FmuPlant) -> None:
    out = _run(plant, [(0.0, 0.0)] * 500, 0.01, v0=1.0, omega0=2.0)
    energy = out[:, IDX["E_kin"]]
    analytic = 0.5 * M11 * 1.0**2 + 0.5 * M22 * 2.0**2
    assert energy[0] == pytest.approx(analytic, rel=1e-12)
    assert np.max(np.abs(energy - analytic)) < 1e-7 * analytic
    # ... while v and omega exchange energy through the m l terms (errata.md)
    v = out[:, IDX["v"]]
    assert np.ptp(v) > 0.1


def test_equal_torques_from_rest_match_the_analytic_solution(plant: FmuPlant) -> None:
    tau = 2.0
    out = _run(plant, [(tau, tau)] * 300, 0.01)
    t = np.arange(out.shape[0]) * 0.01
    v_exact = 2 * tau / (P.r * M11) * t
    np.testing.assert_allclose(out[:, IDX["v"]], v_exact, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(out[:, IDX["x"]], 0.5 * v_exact * t, rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(out[:, IDX["omega"]])) < 1e-12
    assert np.max(np.abs(out[:, IDX["y"]])) < 1e-12


def test_pure_spin_with_centred_mass_matches_the_analytic_solution(plant: FmuPlant) -> None:
    """With l = 0, opposite torques spin the robot in place: omega = 2 L tau t / (r M22)."""
    params = RobotParams(l=0.0)
    m22 = params.Ig + 2 * params.L**2 * params.Iwm / params.r**2
    tau = 1.5
    out = _run(plant, [(tau, -tau)] * 200, 0.01, params=params)
    t = np.arange(out.shape[0]) * 0.01
    omega_exact = 2 * params.L * tau / (params.r * m22) * t
    np.testing.assert_allclose(out[:, IDX["omega"]], omega_exact, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(out[:, IDX["theta"]], 0.5 * omega_exact * t, rtol=1e-9,
                               atol=1e-12)
    assert np.max(np.abs(out[:, IDX["v"]])) < 1e-12
    # the wheels turn opposite ways at (v +- L omega) / r
    np.testing.assert_allclose(out[:, IDX["omega_r"]], params.L * omega_exact / params.r,
                               rtol=1e-9, atol=1e-12)


def test_offset_centre_of_gravity_makes_a_spin_push_forward(plant: FmuPlant) -> None:
    """With l > 0 the centrifugal term m l omega^2 of eq. 18 drives v; the FMU shows it."""
    out = _run(plant, [(1.0, -1.0)] * 100, 0.01)
    assert out[-1, IDX["v"]] > 1e-3


def test_x_G_is_l_ahead_of_B(plant: FmuPlant) -> None:
    out = _run(plant, [(1.0, 0.5)] * 200, 0.01, start=Pose(1.0, -2.0, 0.3))
    th = out[:, IDX["theta"]]
    np.testing.assert_allclose(out[:, IDX["x_G"]], out[:, IDX["x"]] + P.l * np.cos(th),
                               atol=1e-12)
    np.testing.assert_allclose(out[:, IDX["y_G"]], out[:, IDX["y"]] + P.l * np.sin(th),
                               atol=1e-12)


def test_fmu_agrees_with_the_reference_implementation(plant: FmuPlant) -> None:
    from wmr.core.physics import ReferencePlant

    rng = np.random.default_rng(7)
    torques = [tuple(x) for x in rng.uniform(-3, 3, size=(400, 2))]
    params = RobotParams(b_f=0.05, tau_c=0.2)
    start = Pose(0.5, -1.0, 0.7)
    fmu_out = _run(plant, torques, 0.01, params=params, start=start, v0=0.3, omega0=-0.2)
    ref = ReferencePlant()
    ref_out = _run(ref, torques, 0.01, params=params, start=start, v0=0.3,  # type: ignore[arg-type]
                   omega0=-0.2)
    ref.close()
    np.testing.assert_allclose(fmu_out, ref_out, rtol=1e-6, atol=1e-7)


def test_fmi2_and_fmi3_give_the_same_trajectory(fmu2: object, fmu3: object) -> None:
    torques = [(math.sin(0.05 * k), math.cos(0.03 * k)) for k in range(300)]
    with FmuPlant(fmu2) as p2, FmuPlant(fmu3) as p3:  # type: ignore[arg-type]
        np.testing.assert_array_equal(_run(p2, torques, 0.01), _run(p3, torques, 0.01))


def test_one_10ms_step_equals_ten_1ms_steps(plant: FmuPlant) -> None:
    torques = [(math.sin(0.1 * k), -math.cos(0.07 * k)) for k in range(100)]
    coarse = _run(plant, torques, 0.01)
    fine_rows = [plant.reset(P, Pose(0, 0, 0)).copy()]
    for tr, tl in torques:
        for _ in range(10):
            out = plant.step(tr, tl, 0.001)
        fine_rows.append(out.copy())
    np.testing.assert_allclose(coarse, np.array(fine_rows), rtol=1e-8, atol=1e-9)


def test_parameters_change_the_result_as_the_physics_says(plant: FmuPlant) -> None:
    heavy = RobotParams(m=50.0)
    v_light = _run(plant, [(2.0, 2.0)] * 100, 0.01)[-1, IDX["v"]]
    v_heavy = _run(plant, [(2.0, 2.0)] * 100, 0.01, params=heavy)[-1, IDX["v"]]
    m11_heavy = heavy.m + 2 * heavy.Iwm / heavy.r**2
    assert v_light / v_heavy == pytest.approx(m11_heavy / M11, rel=1e-9)
    # viscous friction makes a free-rolling robot slow down
    out = _run(plant, [(0.0, 0.0)] * 100, 0.01, params=RobotParams(b_f=0.5), v0=1.0)
    assert out[-1, IDX["v"]] < 0.9
    # start values set through FMI move the start
    out = _run(plant, [], 0.01, start=Pose(3.0, -4.0, 1.0))
    assert out[0, IDX["x"]] == 3.0 and out[0, IDX["y"]] == -4.0 and out[0, IDX["theta"]] == 1.0


def test_two_instances_do_not_interfere(built: object) -> None:
    fmus = built.fmus  # type: ignore[attr-defined]
    torques_a = [(1.0, 0.5)] * 50
    torques_b = [(-0.5, 2.0)] * 50
    with FmuPlant(fmus[3]) as alone:
        a_alone = _run(alone, torques_a, 0.01)
    with FmuPlant(fmus[3], "a") as a, FmuPlant(fmus[3], "b") as b:
        rows_a = [a.reset(P, Pose(0, 0, 0)).copy()]
        b.reset(RobotParams(m=40.0), Pose(5, 5, 1))
        for ta, tb in zip(torques_a, torques_b, strict=True):
            rows_a.append(a.step(*ta, 0.01).copy())
            b.step(*tb, 0.01)
    np.testing.assert_array_equal(np.array(rows_a), a_alone)


def test_saved_state_replays_bit_for_bit(plant: FmuPlant) -> None:
    plant.reset(P, Pose(0, 0, 0))
    for k in range(50):
        plant.step(math.sin(k), 1.0, 0.01)
    snap = plant.get_state()
    first = np.array([plant.step(0.3 * k, -0.2, 0.01).copy() for k in range(50)])
    plant.set_state(snap)
    second = np.array([plant.step(0.3 * k, -0.2, 0.01).copy() for k in range(50)])
    np.testing.assert_array_equal(first, second)
    blob = plant.serialize_state(snap)
    restored = plant.deserialize_state(blob, snap[1:])
    plant.set_state(restored)
    third = np.array([plant.step(0.3 * k, -0.2, 0.01).copy() for k in range(50)])
    np.testing.assert_array_equal(first, third)


@pytest.mark.parametrize("field, value", [("m", -1.0), ("r", 0.0), ("Ig", -0.1),
                                          ("b_f", math.nan)])
def test_bad_parameters_give_an_error_status(plant: FmuPlant, field: str, value: float) -> None:
    # Bypass RobotParams' own checks: the FMU itself must refuse the value.
    bad = RobotParams()
    object.__setattr__(bad, field, value)
    with pytest.raises(FmuError):
        plant.reset(bad, Pose(0, 0, 0))


@pytest.mark.parametrize("tau", [math.nan, math.inf])
def test_non_finite_torque_gives_an_error_not_nan(plant: FmuPlant, tau: float) -> None:
    plant.reset(P, Pose(0, 0, 0))
    good = plant.step(1.0, 1.0, 0.01).copy()
    with pytest.raises(FmuError, match="tau_r"):
        plant.step(tau, 1.0, 0.01)
    assert np.all(np.isfinite(good))

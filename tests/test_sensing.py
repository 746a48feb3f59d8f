"""Sensor models, the pose EKF, and the sensing hooks of the master loop (wmr.core.sensing)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import stats

from wmr.apps.batch.spec import load_batch, parse_batch
from wmr.apps.batch.summary import summary_table
from wmr.config.scenario import Overrides, expand, load_scenario, parse_scenario, with_overrides
from wmr.core.closedloop import run_closed_loop
from wmr.core.control.from_spec import SpecController
from wmr.core.physics import ReferencePlant
from wmr.core.plant import Pose, RobotParams
from wmr.core.runlog import MemoryLog
from wmr.core.runspec import RunSpec
from wmr.core.sensing import Sensing, SensorConfig, preset
from wmr.core.sensing.ekf import PoseEKF
from wmr.core.sensing.models import Encoders, Gps, Schedule, generators
from wmr.infra.errors import ConfigError

H = 0.01
PARAMS = RobotParams()
TRIP = (10.0, 0.0, 0.0, 0.0, 0.0, math.pi)  # start and goal poses: x_m, y_m, heading_rad

DATA = Path(__file__).parent / "data"


def _outputs(x: float, y: float, theta: float, phi_r: float = 0.0,
             phi_l: float = 0.0) -> np.ndarray:
    out = np.zeros(12)
    out[[0, 1, 2, 7, 8]] = (x, y, theta, phi_r, phi_l)
    return out


# -- configuration ---------------------------------------------------------------------------

@pytest.mark.parametrize(("table", "field"), [
    ({"gps_sigma_m": -0.1}, "sensors.gps_sigma_m"),
    ({"gps_latency_s": -0.05}, "sensors.gps_latency_s"),
    ({"compass_latency_s": -1.0}, "sensors.compass_latency_s"),
    ({"gps_rate_hz": 200.0}, "sensors.gps_rate_hz"),
    ({"encoder_rate_hz": 1000.0}, "sensors.encoder_rate_hz"),
    ({"estimator": "ukf"}, "sensors.estimator"),
    ({"estimator": 1}, "sensors.estimator"),
    ({"heading": "gyro"}, "sensors.heading"),
    ({"heading": "none"}, "sensors.heading"),  # estimator none has no heading then
    ({"gps_sigma": 0.1}, "sensors.gps_sigma"),
    ({"gps_dropout_probability": 1.0}, "sensors.gps_dropout_probability"),
    ({"gps_dropout_windows": [[5.0, 1.0]]}, "sensors.gps_dropout_windows[0]"),
    ({"encoder_counts_per_rev": 10.5}, "sensors.encoder_counts_per_rev"),
    ({"seed": -1}, "sensors.seed"),
    ({"wheel_radius_error_frac": 0.7}, "sensors.wheel_radius_error_frac"),
])
def test_bad_sensor_config_names_the_field(table: dict[str, Any], field: str) -> None:
    data = {"start": [0, 0, 0], "goal": [1, 0, 0], "sensors": table}
    with pytest.raises(ConfigError) as err:
        parse_scenario(data)
    assert err.value.field == field
    assert "\n" not in str(err.value) and str(err.value).startswith(field)


def test_scenario_sensors_table_and_overrides() -> None:
    (spec,) = parse_scenario({"start": [0, 0, 0], "goal": [1, 0, 0],
                              "sensors": {"estimator": "ekf", "gps_sigma_m": 0.03}}).runs
    assert spec.sensors == SensorConfig(estimator="ekf", gps_sigma_m=0.03)
    (plain,) = parse_scenario({"start": [0, 0, 0], "goal": [1, 0, 0]}).runs
    assert plain.sensors is None
    assert with_overrides(plain, Overrides(sensors={"gps_sigma_m": 0.5})).sensors == SensorConfig(
        gps_sigma_m=0.5)
    with pytest.raises(ConfigError, match=r"sensors\.gps_rate_hz"):
        with_overrides(plain, Overrides(period_s=0.5, sensors={"gps_rate_hz": 10.0}))


# -- sensor models ---------------------------------------------------------------------------

def test_schedule_rate_and_delay() -> None:
    for rate, latency in ((10.0, 0.05), (7.0, 0.013), (100.0, 0.0), (0.5, 1.0)):
        s = Schedule(rate, latency, H)
        n = 100_000
        count = sum(s.samples(k) for k in range(n))
        assert abs(count - rate * n * H) <= 1.0
        assert s.delay_steps * H >= latency - 1e-12 and (s.delay_steps - 1) * H < latency


def test_gps_noise_statistics_rate_and_latency() -> None:
    cfg = SensorConfig(gps_rate_hz=10.0, gps_latency_s=0.05, gps_sigma_m=0.3)
    gps = Gps(cfg, H, generators(3, TRIP))
    steps = 200_000
    fixes = []
    for n in range(steps):
        x, y = 0.001 * n, -0.002 * n  # a moving truth
        gps.measure(n, x, y)
        fixes += [(f, 0.001 * f.step, -0.002 * f.step) for f in gps.arrivals(n)]
    k = len(fixes)
    assert abs(k - 10.0 * steps * H) <= 1
    err = np.array([(f.value[0] - x, f.value[1] - y) for f, x, y in fixes])
    se_mean = 0.3 / math.sqrt(k)
    assert np.all(np.abs(err.mean(axis=0)) < 4.0 * se_mean)
    se_sigma = 0.3 / math.sqrt(2 * k)
    assert np.all(np.abs(err.std(axis=0, ddof=1) - 0.3) < 4.0 * se_sigma)
    assert {(f.arrival - f.step) for f, _, _ in fixes} == {5}
    assert abs(np.corrcoef(err[:-1, 0], err[1:, 0])[0, 1]) < 4.0 / math.sqrt(k)


def test_gps_bias_walk_and_dropouts() -> None:
    q = 0.1  # m / sqrt(s)
    cfg = SensorConfig(gps_rate_hz=10.0, gps_bias_walk_m_per_sqrt_s=q,
                       gps_dropout_probability=0.2, gps_dropout_windows=((10.0, 20.0),))
    n_runs, steps = 400, 3000  # 30 s each
    finals = []
    kept = 0
    in_window = 0
    for seed in range(n_runs):
        gps = Gps(cfg, H, generators(seed, TRIP))
        for n in range(steps):
            gps.measure(n, 0.0, 0.0)
            for f in gps.arrivals(n):
                kept += 1
                in_window += 10.0 <= f.step * H <= 20.0
        finals.append(gps.bias_m.copy())
    # the bias after T has sigma q sqrt(T), T = time of the last sample (29.9 s)
    b = np.array(finals)
    expected = q * math.sqrt((steps - 10) * H)
    assert abs(b.std(ddof=1) - expected) < 4.0 * expected / math.sqrt(2 * b.size)
    assert in_window == 0
    samples = n_runs * (300 - 101)  # samples outside the window of [10, 20] s
    assert abs(kept / samples - 0.8) < 4.0 * math.sqrt(0.16 / samples)


def test_compass_statistics_and_encoder_quantisation() -> None:
    cfg = SensorConfig(compass_sigma_deg=2.0, compass_rate_hz=25.0, compass_latency_s=0.1,
                       encoder_counts_per_rev=512)
    sensing = Sensing(cfg, H, PARAMS, Pose(0.0, 0.0, 3.1), Pose(1.0, 0.0, 0.0))
    assert sensing.compass is not None
    comp = sensing.compass
    errs, delays = [], set()
    for n in range(100_000):
        comp.measure(n, 3.1)  # near +pi: the noise wraps
        for f in comp.arrivals(n):
            errs.append(math.remainder(f.value[0] - 3.1, 2 * math.pi))
            delays.add(f.arrival - f.step)
    e = np.array(errs)
    assert abs(len(e) - 25.0 * 1000) <= 3 and delays == {10}
    sig = math.radians(2.0)
    assert abs(e.mean()) < 4 * sig / math.sqrt(len(e))
    assert abs(e.std(ddof=1) - sig) < 4 * sig / math.sqrt(2 * len(e))
    enc = Encoders(cfg, H)
    q = 2 * math.pi / 512
    phi = np.random.default_rng(0).uniform(-50, 50, 20_000)
    qerr = np.array([p - enc.read(p) for p in phi])
    assert qerr.min() >= 0.0 and qerr.max() < q
    assert abs(qerr.mean() - q / 2) < 4 * q / math.sqrt(12 * len(qerr))
    assert abs(qerr.std() - q / math.sqrt(12)) < 0.02 * q


def test_streams_are_independent_and_reproducible() -> None:
    a = generators(7, TRIP)["gps_noise"].normal(size=5)
    assert np.array_equal(a, generators(7, TRIP)["gps_noise"].normal(size=5))
    assert not np.array_equal(a, generators(8, TRIP)["gps_noise"].normal(size=5))
    for i in range(len(TRIP)):  # any part of the start or the goal, by one ulp
        other = [*TRIP]
        other[i] = math.nextafter(other[i], math.inf)
        assert not np.array_equal(a, generators(7, other)["gps_noise"].normal(size=5))
    negative_zero = [-0.0 if v == 0.0 else v for v in TRIP]
    assert np.array_equal(a, generators(7, negative_zero)["gps_noise"].normal(size=5))
    # a dropout probability changes which fixes arrive, not their noise
    base = SensorConfig(gps_sigma_m=1.0)
    g1 = Gps(base, H, generators(1, TRIP))
    g2 = Gps(replace(base, gps_dropout_probability=0.5), H, generators(1, TRIP))
    v1, v2 = {}, {}
    for n in range(2000):
        g1.measure(n, 0.0, 0.0)
        g2.measure(n, 0.0, 0.0)
        v1.update({f.step: f.value for f in g1.arrivals(n)})
        v2.update({f.step: f.value for f in g2.arrivals(n)})
    assert 0 < len(v2) < len(v1) and all(v1[k] == v for k, v in v2.items())


# -- the EKF ---------------------------------------------------------------------------------

def test_ekf_textbook_static_fixes() -> None:
    """A robot at rest, fixes of variance R: the posterior is the precision-weighted mean,
    P_n = 1 / (1/P0 + n/R) (the textbook recursive estimate of a constant)."""
    p0, sigma = 4.0, 0.5
    rng = np.random.default_rng(1)
    z = rng.normal(0.0, sigma, (50, 2)) + np.array([3.0, -1.0])
    ekf = PoseEKF((0.0, 0.0, 0.0), np.diag([p0, p0, 0.1]), 0.3)
    for i, (zx, zy) in enumerate(z):
        ekf.predict(0.0, 0.0)
        ekf.update_position(zx, zy, sigma, i + 1)
    n, r = len(z), sigma**2
    post_var = 1.0 / (1.0 / p0 + n / r)
    assert ekf.p[0, 0] == pytest.approx(post_var, rel=1e-12)
    assert ekf.p[1, 1] == pytest.approx(post_var, rel=1e-12)
    mean = post_var * z.sum(axis=0) / r  # prior mean 0
    assert ekf.s[:2] == pytest.approx(mean, rel=1e-12)
    assert ekf.p[2, 2] == pytest.approx(0.1, rel=1e-12)


def test_ekf_straight_run_with_exact_odometry_is_exact() -> None:
    """Exact odometry on a straight line (any heading): the estimate is the truth to 1e-9."""
    theta = math.radians(35.0)
    ekf = PoseEKF((1.0, 2.0, theta), np.zeros((3, 3)), 0.3)
    x, y = 1.0, 2.0
    rng = np.random.default_rng(2)
    for k in range(1, 5001):
        d = float(rng.uniform(0.0, 0.02))
        x += d * math.cos(theta)
        y += d * math.sin(theta)
        ekf.predict(d, d)
        if k % 10 == 0:  # exact fixes, 5 steps late
            ekf.update_position(x - 0.0, y, 0.0, k)
    assert ekf.pose == pytest.approx((x, y, theta), abs=1e-9)


def test_ekf_run_on_the_plant_with_exact_sensors_matches_truth() -> None:
    """In closed loop with exact encoders and no fixes noise, on a straight segment."""
    spec = RunSpec("straight", Pose(0.0, 0.0, 0.0), Pose(3.0, 0.0, 0.0), t_max_s=4.0,
                   sensors=SensorConfig(estimator="ekf", heading="none",
                                        initial_heading_sigma_deg=0.0,
                                        odometry_noise_m2_per_m=0.0, gps_rate_hz=1.0))
    res = run_closed_loop(spec, ReferencePlant(), controller=SpecController())
    assert res.sensing is not None
    est = res.sensing.est_pose[-1]
    assert est[0] == pytest.approx(res.final_pose.x_m, abs=1e-9)
    assert est[1] == pytest.approx(res.final_pose.y_m, abs=1e-9)
    assert est[2] == pytest.approx(res.final_pose.heading_rad, abs=1e-9)


def test_wheel_radius_error_scales_the_odometry() -> None:
    """With no fix after the first, the EKF dead-reckons: its distance is (1 + e) times the
    true one on a straight run."""
    err = 0.02
    spec = RunSpec("scale", Pose(0.0, 0.0, 0.0), Pose(3.0, 0.0, 0.0), t_max_s=4.0,
                   sensors=SensorConfig(estimator="ekf", heading="none", gps_rate_hz=0.1,
                                        initial_heading_sigma_deg=0.0,
                                        wheel_radius_error_frac=err))
    res = run_closed_loop(spec, ReferencePlant(), controller=SpecController())
    assert res.sensing is not None and len(res.sensing.gps_t_ns) == 1
    assert res.sensing.est_pose[-1][0] == pytest.approx((1 + err) * res.final_pose.x_m,
                                                        rel=1e-9)


def _simulate(seed: int, latency_steps: int, compensate: bool, steps: int = 600,
              sigma: float = 0.05, k2: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """A curvy run with noisy odometry (per the filter's model) and noisy, late fixes.

    Returns the errors (truth - estimate) and covariances at every step."""
    rng = np.random.default_rng(seed)
    half = 0.3
    p0 = np.diag([sigma**2, sigma**2, math.radians(3.0) ** 2])
    truth = np.zeros(3)
    s0 = truth + rng.multivariate_normal(np.zeros(3), p0)
    ekf = PoseEKF(tuple(s0), p0, half, odometry_var_per_m=k2, history_steps=latency_steps + 1,
                  compensate_latency=compensate)
    hist = [truth.copy()]
    errs, covs = [], []
    for k in range(1, steps + 1):
        t = k * H
        v, w = 1.0, 0.8 * math.sin(0.5 * t)
        d_r = (v + w * half) * H
        d_l = (v - w * half) * H
        # the truth moves by the odometry model with the true wheel travels
        ds, dth = 0.5 * (d_r + d_l), (d_r - d_l) / (2 * half)
        th_m = truth[2] + 0.5 * dth
        truth = truth + np.array([ds * math.cos(th_m), ds * math.sin(th_m), dth])
        hist.append(truth.copy())
        m_r = d_r + rng.normal(0.0, math.sqrt(k2 * abs(d_r)))
        m_l = d_l + rng.normal(0.0, math.sqrt(k2 * abs(d_l)))
        ekf.predict(m_r, m_l)
        m = k - latency_steps
        if m > 0 and m % 10 == 0:
            z = hist[m][:2] + rng.normal(0.0, sigma, 2)
            ekf.update_position(z[0], z[1], sigma, m)
        e = truth - ekf.s
        e[2] = math.remainder(e[2], 2 * math.pi)
        errs.append(e)
        covs.append(ekf.p.copy())
    return np.array(errs), np.array(covs)


def test_ekf_nees_is_consistent() -> None:
    """Normalised estimation error squared, averaged over seeds, within its chi-square bounds
    (Bar-Shalom, Li, Kirubarajan, ch. 5.4) at every checked step."""
    n_runs = 60
    runs = [_simulate(seed, 0, True) for seed in range(n_runs)]
    checks = range(49, 600, 50)
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], df=3 * n_runs) / n_runs
    for k in checks:
        nees = np.mean([e[k] @ np.linalg.solve(p[k], e[k]) for e, p in runs])
        assert lo < nees < hi, (k, nees, lo, hi)


def test_ekf_latency_handling_beats_fixes_on_arrival() -> None:
    delay = 20  # 0.2 s at 1 m/s: a fix is 0.2 m old when it arrives
    rms = {}
    for compensate in (True, False):
        sq = [np.mean(_simulate(seed, delay, compensate)[0][:, :2] ** 2) for seed in range(20)]
        rms[compensate] = math.sqrt(float(np.mean(sq)))
    assert rms[True] < 0.5 * rms[False], rms


def test_ekf_late_fix_equals_a_fix_on_time_once_it_arrived() -> None:
    rng = np.random.default_rng(4)
    travels = rng.uniform(0.0, 0.02, (60, 2))
    p0 = np.diag([0.01, 0.01, 0.01])
    on_time = PoseEKF((0.0, 0.0, 0.1), p0, 0.3, odometry_var_per_m=1e-3, history_steps=30)
    late = PoseEKF((0.0, 0.0, 0.1), p0, 0.3, odometry_var_per_m=1e-3, history_steps=30)
    for k, (d_r, d_l) in enumerate(travels, start=1):
        for f in (on_time, late):
            f.predict(d_r, d_l)
        if k == 20:
            on_time.update_position(0.3, 0.05, 0.05, 20)
            on_time.update_heading(0.2, 0.05, 20)
        if k == 45:  # 25 steps late, filed at step 20
            late.update_heading(0.2, 0.05, 20)
            late.update_position(0.3, 0.05, 0.05, 20)
    assert late.s == pytest.approx(on_time.s, abs=1e-12)
    assert late.p == pytest.approx(on_time.p, abs=1e-12)


# -- the master loop -------------------------------------------------------------------------

def test_sensors_off_is_bit_identical_and_reports_true_errors() -> None:
    """No [sensors]: the same rows as perfect state feedback, and estimate = truth.

    And a sensor suite that is exact (no noise, fixes every step without latency, raw
    estimator, exact encoders) drives the robot exactly as perfect feedback does."""
    (spec,) = expand(load_scenario("fig11"))
    spec = replace(spec, t_max_s=8.0)
    rec = MemoryLog()
    res = run_closed_loop(spec, ReferencePlant(), rec, controller=SpecController())
    assert res.sensing is None
    assert res.estimated_final_position_error_m == res.final_position_error_m
    assert res.estimated_final_heading_error_rad == res.final_heading_error_rad
    exact = SensorConfig(gps_rate_hz=100.0, compass_rate_hz=100.0)
    rec2 = MemoryLog()
    res2 = run_closed_loop(with_overrides(spec, Overrides(sensors=exact)), ReferencePlant(), rec2,
                           controller=SpecController())
    assert np.array_equal(rec.block, rec2.block)
    assert res2.final_pose == res.final_pose
    # the rows as the code before wmr.core.sensing wrote them (commit 9cba7f7), this 8 s fig11
    # run on the reference plant: tests/data/fig11_8s_rows_9cba7f7.npz (docs/testing.md).  A
    # SHA-256 of them pinned one machine's bits: the same code on another CPU (numpy's SIMD
    # kernels, libm) writes other last bits, so the rows are compared to 1e-12 relative; a
    # behavioural change moves them far more
    rows = rec.block
    reference = np.load(DATA / "fig11_8s_rows_9cba7f7.npz")["rows"]
    assert rows.shape == reference.shape, (
        f"the rows without sensors changed since 9cba7f7: {rows.shape} rows x signals against "
        f"{reference.shape}, {res.status} at {res.final_pose}")
    np.testing.assert_allclose(rows, reference, rtol=1e-12, atol=1e-12,
                               err_msg="the rows without sensors changed since 9cba7f7")


def test_run_ids_without_sensors_are_unchanged() -> None:
    """The ids of the shipped batches, as before sensors existed (commit 9cba7f7)."""
    assert [r.run_id for r in load_batch("fig10").runs[:2]] == ["0000-6967d8ca",
                                                                 "0001-70fb44b4"]
    assert load_batch("sweep_gains").runs[0].run_id == "0000-6dbddae1"


def test_batch_sweeps_sensor_fields() -> None:
    data = {"name": "s", "start": [0, 0, 0], "goal": [1, 0, 0],
            "grid": {"sensors": {"gps_sigma_m": [0.01, 0.05]}, "stop_radius_m": [0.05, 0.1]},
            "list": [{"name": "raw", "sensors": {"estimator": "none"}},
                     {"name": "ekf", "sensors": {"estimator": "ekf", "heading": "none"}}],
            "random": {"seed": 1, "n": 2,
                       "sensors": {"seed": {"dist": "choice", "values": [1, 2, 3]}}}}
    batch = parse_batch(data)
    assert len(batch.runs) == 2 * 2 * 2 * 2
    assert "sensors.gps_sigma_m" in batch.input_columns
    r = batch.runs[-1]
    assert r.spec.sensors is not None and r.spec.sensors.estimator == "ekf"
    assert r.spec.sensors.gps_sigma_m == 0.05 and r.inputs["sensors.estimator"] == "ekf"
    assert isinstance(r.spec.sensors.seed, int)
    table = summary_table(batch.runs, batch.input_columns,
                          {r.run_id: {"status": "converged"} for r in batch.runs})
    assert table.column("sensors.estimator").to_pylist()[:2] == ["none", "none"]
    assert table.column("sensors.gps_sigma_m").to_pylist()[0] == 0.01
    bad = dict(data, grid={"sensors": {"gps_sigma_m": [0.01, -1.0]}})
    with pytest.raises(ConfigError, match=r"^grid\.sensors\.gps_sigma_m: must be >= 0"):
        parse_batch(bad)
    with pytest.raises(ConfigError, match=r"^grid\.sensors\.estimator\[0\]: must be a name"):
        parse_batch(dict(data, grid={"sensors": {"estimator": [1.0]}}))


def test_wmr_run_sensors_gps_logs_fixes_and_estimate(tmp_path: Path) -> None:
    """``wmr run --sensors gps`` on the FMU: the Fig. 11 case converges; the log has the true
    pose, the fixes and the estimate; the replay draws all three."""
    import io
    import json
    from contextlib import redirect_stderr, redirect_stdout

    import rerun.chunk as rrc

    from wmr.adapters.mcap import read_run
    from wmr.adapters.mcap.sensing import read_sensing
    from wmr.cli import main

    out = tmp_path / "gps.mcap"
    buf, err = io.StringIO(), io.StringIO()
    with redirect_stdout(buf), redirect_stderr(err):
        rc = main(["run", "--sensors", "gps", "--out", str(out), "--json"])
    assert rc == 0, err.getvalue()
    record = json.loads(buf.getvalue().strip().splitlines()[-1])
    assert record["status"] == "converged"
    assert record["estimated_final_position_error_m"] <= 0.05
    assert record["final_position_error_m"] < 0.1
    run = read_run(out)
    assert json.loads(run.metadata["run"]["sensors"])["gps_sigma_m"] == 0.02
    trace = read_sensing(out)
    assert trace is not None
    assert len(trace.est_t_ns) == run.n_steps
    assert np.array_equal(trace.est_t_ns, run.t_ns)
    # the fixes scatter about the true path by about their sigma
    idx = np.searchsorted(run.t_ns, trace.gps_t_ns)
    d = trace.gps_xy_m - np.column_stack([run.signals["x_m"][idx], run.signals["y_m"][idx]])
    assert 0.01 < float(np.std(d)) < 0.04
    from mcap.reader import make_reader

    from wmr.adapters.mcap.sensing import COVARIANCE_TOPIC, PoseCovariance
    with open(out, "rb") as f:
        cov = [PoseCovariance.FromString(m.data) for _, _, m in
               make_reader(f).iter_messages(topics=[COVARIANCE_TOPIC])]
    assert len(cov) == run.n_steps
    assert all(c.xx_m2 > 0 and c.yy_m2 > 0 and c.theta_theta_rad2 > 0
               and c.xy_m2**2 <= c.xx_m2 * c.yy_m2 for c in cov)
    assert math.sqrt(cov[-1].xx_m2) < 0.02  # the filter knows better than one fix
    rrd = tmp_path / "gps.rrd"
    with redirect_stdout(io.StringIO()), redirect_stderr(io.StringIO()):
        assert main(["replay", str(out), "--rrd", str(rrd)]) == 0
    entities = {chunk.entity_path for chunk in rrc.RrdReader(rrd).stream()}
    assert {"/runs/gps/world/path", "/runs/gps/world/gps",
            "/runs/gps/world/estimate"} <= entities


def test_noisy_run_is_reproducible_and_seeded() -> None:
    (spec,) = expand(load_scenario("fig11"))
    spec = with_overrides(replace(spec, t_max_s=5.0), Overrides(sensors=preset("gps")))
    a = run_closed_loop(spec, ReferencePlant(), controller=SpecController())
    b = run_closed_loop(spec, ReferencePlant(), controller=SpecController())
    c = run_closed_loop(with_overrides(spec, Overrides(sensors={"seed": 1})), ReferencePlant(),
                        controller=SpecController())
    assert a.sensing is not None and b.sensing is not None and c.sensing is not None
    assert np.array_equal(a.sensing.est_pose, b.sensing.est_pose)
    assert a.final_pose == b.final_pose
    assert not np.array_equal(a.sensing.gps_xy_m, c.sensing.gps_xy_m)
    assert len(a.sensing.gps_t_ns) == 50  # 10 Hz for 5 s, the last 5 fixes still in flight
    assert np.all(a.sensing.gps_arrival_ns - a.sensing.gps_t_ns == 50_000_000)


def _fix_errors(spec: RunSpec) -> tuple[np.ndarray, np.ndarray]:
    """``spec`` on the reference plant: its GPS fixes minus the true position each measured,
    and the true path, m."""
    rec = MemoryLog()
    res = run_closed_loop(spec, ReferencePlant(), rec, controller=SpecController())
    assert res.sensing is not None and len(res.sensing.gps_t_ns) > 10
    t_ns, xy_m = rec.t_ns, rec.block[:, :2]  # x_m, y_m lead the rows
    idx = np.searchsorted(t_ns, res.sensing.gps_t_ns)
    assert np.array_equal(t_ns[idx], res.sensing.gps_t_ns)
    return res.sensing.gps_xy_m - xy_m[idx], xy_m


def test_a_gains_variant_sees_the_noise_of_its_trip_not_of_its_name() -> None:
    """Common random numbers: ``fig11-K_ptheta=17`` (a variant named after its override)
    drives another path through the very same GPS noise as ``fig11``."""
    from wmr.config.naming import run_name

    (base,) = expand(load_scenario("fig11"))
    base = with_overrides(replace(base, t_max_s=3.0), Overrides(sensors=preset("gps")))
    tuned = with_overrides(base, Overrides(gains={"K_ptheta": 17.0}))
    tuned = replace(tuned, name=run_name(base, tuned))
    assert tuned.name == "fig11-K_ptheta=17"
    (e_base, path_base), (e_tuned, path_tuned) = _fix_errors(base), _fix_errors(tuned)
    assert not np.allclose(path_base, path_tuned, rtol=0.0, atol=1e-3)
    np.testing.assert_allclose(e_tuned, e_base, rtol=0.0, atol=1e-12)


def test_batch_runs_share_noise_per_trip_and_random_starts_do_not() -> None:
    """A batch of 2 gains x 2 random starts: the two gains see one noise realisation per
    start, the two starts two independent ones."""
    data = {"name": "crn", "start": [10, 0, 0], "goal": [0, 0, 180], "max_time_s": 2.0,
            "sensors": {"estimator": "ekf", "heading": "none", "gps_sigma_m": 0.02},
            "grid": {"gains": {"K_ptheta": [1.0, 17.0]}},
            "random": {"seed": 3, "n": 2,
                       "start": {"r_m": {"dist": "uniform", "low": 3.0, "high": 12.0},
                                 "bearing_deg": {"dist": "uniform", "low": -180.0,
                                                 "high": 180.0}}}}
    runs = parse_batch(data).runs
    by_start: dict[Pose, list[np.ndarray]] = {}
    for r in runs:
        by_start.setdefault(r.spec.start, []).append(_fix_errors(r.spec)[0])
    assert len(runs) == 4 and len({r.spec.name for r in runs}) == 4 and len(by_start) == 2
    (a1, a2), (b1, b2) = by_start.values()
    np.testing.assert_allclose(a2, a1, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(b2, b1, rtol=0.0, atol=1e-12)
    n = min(len(a1), len(b1))
    # independent streams: the noise of the two starts is uncorrelated (4 standard errors)
    r = np.corrcoef(a1[:n].ravel(), b1[:n].ravel())[0, 1]
    assert abs(r) < 4.0 / math.sqrt(2 * n)


def test_fig11_converges_with_2cm_gps_at_10hz_and_50ms() -> None:
    """The issue's acceptance case, on the estimate; the true errors beside it."""
    (spec,) = expand(load_scenario("fig11"))
    res = run_closed_loop(with_overrides(spec, Overrides(sensors=preset("gps"))), ReferencePlant(),
                          controller=SpecController())
    assert res.status == "converged", res.message
    assert res.estimated_final_position_error_m <= spec.stop_radius_m
    assert res.final_position_error_m < 2 * spec.stop_radius_m
    assert res.final_heading_error_rad < math.radians(2.0)
    assert res.final_position_error_m != res.estimated_final_position_error_m


def test_study_epsilon_table_and_figure(tmp_path: Path) -> None:
    """The report's sensing section on a made-up summary: the epsilon needed per sigma."""
    import pyarrow as pa

    from wmr.apps.sensing_study import sensing_section, study

    rows = []
    for variant in ("raw", "ekf"):
        for sigma in (0.01, 0.1):
            for eps in (0.05, 0.2, 0.5):
                for k in range(10):
                    # raw fails below eps = 2 sigma, and once at (0.01, 0.2); ekf never fails
                    fail = variant == "raw" and (eps < 2 * sigma or (sigma, eps, k) == (
                        0.01, 0.2, 3))
                    # ekf once converged but truly outside epsilon: no success
                    outside = variant == "ekf" and (sigma, eps, k) == (0.1, 0.05, 0)
                    rows.append({"variant": variant, "sensors.gps_sigma_m": sigma,
                                 "stop_radius_m": eps,
                                 "status": "timeout" if fail else "converged",
                                 "final_position_error_m": 0.06 if outside else sigma / 2,
                                 "final_heading_error_rad": 0.01})
    table = pa.Table.from_pylist(rows)
    st = study(table)
    assert st is not None and st.variants == ("raw", "ekf")
    assert st.epsilon_for("ekf", 0.1) == 0.2
    assert st.cells[("ekf", 0.1, 0.05)].converged == 10
    assert st.epsilon_for("raw", 0.01) == 0.5  # 9/10 at 0.2 is below 99 %
    assert st.epsilon_for("raw", 0.1) == 0.2
    assert st.epsilon_for("raw", 0.1, target=1.0) == 0.2
    lines = sensing_section(table, tmp_path)
    assert "| 0.01 | 0.5 | 0.05 |" in lines and "| 0.1 | 0.2 | 0.2 |" in lines
    assert (tmp_path / "sensing.png").stat().st_size > 10_000
    assert sensing_section(table.drop_columns(["stop_radius_m"]), tmp_path) == []


def test_controller_fmu_acts_on_the_estimate_as_python_does(built: Any) -> None:
    """With sensors, the controller FMU gets the estimate, as the Python controller does: the
    same path (the C controller traces the Python one to 1e-9, docs/fmu.md)."""
    from wmr.adapters.fmi.controller import FmuController

    (spec,) = expand(load_scenario("fig11"))
    spec = with_overrides(replace(spec, t_max_s=10.0), Overrides(sensors=preset("gps")))
    py_rows, c_rows = MemoryLog(), MemoryLog()
    py = run_closed_loop(spec, ReferencePlant(), py_rows, controller=SpecController())
    with FmuController(built.controllers[3]) as ctrl:
        c = run_closed_loop(spec, ReferencePlant(), c_rows, controller=ctrl or SpecController())
    assert py.sensing is not None and c.sensing is not None
    np.testing.assert_allclose(c_rows.block, py_rows.block,
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(c.sensing.est_pose, py.sensing.est_pose, rtol=0, atol=1e-9)


def test_read_sensing_of_a_cut_log_keeps_what_was_whole(tmp_path: Path) -> None:
    """The sensing topics are read by the bounded scan, like every other signal: a log cut
    short (a killed run, a truncated copy) gives the fixes and estimates of its whole chunks,
    never an exception from a reader that trusts the file."""
    import contextlib
    import io

    from wmr.adapters.mcap.sensing import read_sensing
    from wmr.cli import main

    out = tmp_path / "gps.mcap"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["run", "--sensors", "gps", "--out", str(out), "--max-time", "2"]) in (0, 3)
    whole = read_sensing(out)
    assert whole is not None and len(whole.est_t_ns) > 100
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(out.read_bytes()[:-200])  # the summary and footer gone, as after a kill
    part = read_sensing(cut)
    assert part is not None
    assert np.array_equal(part.est_t_ns, whole.est_t_ns)
    assert np.array_equal(part.est_pose, whole.est_pose)
    assert np.array_equal(part.gps_xy_m, whole.gps_xy_m)


# -- how the fixes are logged (issue 33, item 11) --------------------------------------------

def _fixes_record() -> Any:
    """A hand-made record: three fixes (full float64 digits, arriving 50 ms after they were
    measured) and two estimates."""
    from wmr.core.sensing.estimator import SensingRecord

    return SensingRecord(
        gps_t_ns=np.array([0, 100_000_000, 200_000_000], np.int64),
        gps_arrival_ns=np.array([50_000_000, 150_000_000, 250_000_000], np.int64),
        gps_xy_m=np.array([[0.1234567890123, -2.0], [10.000000001, 3.3], [-7.5, 1e-9]]),
        est_t_ns=np.array([0, 10_000_000], np.int64),
        est_pose=np.array([[0.0, 0.0, 0.5], [0.01, 0.0, 0.5]]),
        est_cov=np.full((2, 4), np.nan))


def _write_fixes(path: Path) -> Any:
    from wmr.adapters.mcap import RunLogWriter
    from wmr.adapters.mcap.sensing import write_sensing

    rec = _fixes_record()
    log = RunLogWriter(path, run={"scenario": "fixes"}, goal=(1.0, 0.0, 0.0))
    write_sensing(log, rec)
    log.close({"status": "converged"})
    return rec


def test_a_fix_is_logged_as_a_point_without_a_heading(tmp_path: Path) -> None:
    """A GPS fix is a position: decoded with the Foxglove schema embedded in the log (by
    ``mcap-protobuf-support``, as Foxglove's and Lichtblick's readers do), each message on
    ``/sensors/gps`` is a ``foxglove.PointCloud`` of one point at the fix, with no pose and
    no orientation anywhere, so that a 3-D panel draws a point. Seen failing on the fixes as
    ``foxglove.PoseInFrame`` with an identity orientation (an arrow along +x)."""
    from google.protobuf.message import Message
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    path = tmp_path / "fixes.mcap"
    rec = _write_fixes(path)
    with open(path, "rb") as f:
        decoded = list(make_reader(f, decoder_factories=[DecoderFactory()])
                       .iter_decoded_messages(topics=["/sensors/gps"]))
    assert len(decoded) == 3
    assert {schema.name for schema, _, _, _ in decoded} == {"foxglove.PointCloud"}

    def set_fields(msg: Message) -> list[str]:
        """The names of every field set in ``msg``, nested ones included."""
        names = []
        for fd, value in msg.ListFields():
            names.append(fd.name)
            if fd.message_type is not None:  # a message, or a repeated one
                subs = [value] if isinstance(value, Message) else list(value)
                names += [n for v in subs for n in set_fields(v)]
        return names

    for i, (_, _, message, cloud) in enumerate(decoded):
        assert "pose" not in set_fields(cloud) and "orientation" not in set_fields(cloud)
        assert cloud.frame_id == "world"
        assert message.log_time == rec.gps_arrival_ns[i]
        assert cloud.timestamp.ToNanoseconds() == rec.gps_t_ns[i]
        # the point, read through the message's own field table (8: FLOAT64, 1: UINT8)
        fields = {fd.name: (fd.offset, fd.type) for fd in cloud.fields}
        assert len(cloud.data) == cloud.point_stride
        xyz = [np.frombuffer(cloud.data, "<f8", 1, fields[n][0])[0] for n in "xyz"]
        assert [fields[n][1] for n in "xyz"] == [8, 8, 8]
        assert xyz == [rec.gps_xy_m[i, 0], rec.gps_xy_m[i, 1], 0.0]  # float64: exact
        assert {n for n, (_, t) in fields.items() if t == 1} == {"red", "green", "blue", "alpha"}
    from wmr.infra.paths import _REPO_ROOT

    documented = [line for line in (_REPO_ROOT / "docs" / "sensing.md").read_text(
        encoding="utf-8").splitlines() if line.startswith("| `/sensors/gps` |")]
    assert len(documented) == 1 and "| `foxglove.PointCloud` |" in documented[0]


def test_read_sensing_reads_the_fixes_of_new_and_old_logs(tmp_path: Path) -> None:
    """``read_sensing`` (``wmr replay``) gives the fixes back exactly from a new log, and from
    a log written before the fixes were point clouds (``foxglove.PoseInFrame`` each)."""
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    from mcap.writer import Writer

    from wmr.adapters.mcap.schemas import descriptor_set
    from wmr.adapters.mcap.sensing import read_sensing

    new = tmp_path / "new.mcap"
    rec = _write_fixes(new)
    old = tmp_path / "old.mcap"
    with open(old, "wb") as f:  # the old form, written by the mcap library itself
        w = Writer(f)
        w.start()
        sid = w.register_schema("foxglove.PoseInFrame", "protobuf",
                                descriptor_set(PoseInFrame.DESCRIPTOR.file))
        cid = w.register_channel("/sensors/gps", "protobuf", sid)
        for t, arrival, (x, y) in zip(rec.gps_t_ns.tolist(), rec.gps_arrival_ns.tolist(),
                                      rec.gps_xy_m.tolist(), strict=True):
            pose = PoseInFrame(frame_id="world")
            pose.timestamp.FromNanoseconds(t)
            pose.pose.position.x, pose.pose.position.y = x, y
            pose.pose.orientation.w = 1.0
            w.add_message(cid, arrival, pose.SerializeToString(), arrival)
        w.finish()
    for path in (new, old):
        trace = read_sensing(path)
        assert trace is not None, path
        assert np.array_equal(trace.gps_t_ns, rec.gps_t_ns), path
        assert np.array_equal(trace.gps_xy_m, rec.gps_xy_m), path
    new_trace = read_sensing(new)
    assert new_trace is not None and np.array_equal(new_trace.est_t_ns, rec.est_t_ns)

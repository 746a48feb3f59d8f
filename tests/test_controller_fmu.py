"""The controller FMU: one law in two implementations (Python reference, C), proven equal.

The C core (``fmu/src/controller/controller.c``) is compiled with a test-only loop over
arrays, so that 100,000 random controller states run in one call; the Python reference is
:class:`wmr.core.control.PIController` (PointStabiliser and two WheelServos) with its state set
slot by slot.  The built FMUs are then checked as FMUs: validation,
NaN measurements, names and defaults (the sampling in any master:
``tests/test_controller_sampling.py``).
"""

from __future__ import annotations

import ctypes
import math
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu
from mcap.reader import make_reader

from wmr.adapters.fmi.controller import FmuController
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.fmi.slave import remove_stale_folders
from wmr.adapters.mcap import read_run
from wmr.build.controller_interface import (
    INPUTS,
    SIGNAL_OUTPUTS,
    STATES,
    controller_model,
    controller_sources,
    write_controller_core,
)
from wmr.build.fmus import BuildResult
from wmr.build.platforms import CFLAGS
from wmr.cli import main
from wmr.config.scenario import load_scenario
from wmr.core.closedloop import run_closed_loop
from wmr.core.control import ALIGN, Gains, Limits, PIController
from wmr.core.control.from_spec import SpecController
from wmr.core.plant import Pose, RobotParams
from wmr.core.runlog import MemoryLog
from wmr.core.runspec import RunSpec
from wmr.core.signals import COLUMN, CONTROL_SIGNALS, SIGNALS
from wmr.infra import paths
from wmr.infra.errors import ConfigError, FmuError

N_SETS = 200  # parameter sets
N_PER_SET = 500  # states and inputs per parameter set: 100,000 samples in all

_HARNESS = r"""
#include "model.h"
/* test-only: the controller core over arrays of samples (z, u, p) -> (y, z_next) */
__attribute__((visibility("default")))
void harness_sample(int n, const double *z, const double *u, const double *p, double *y,
                    double *z_next) {
    int i;
    for (i = 0; i < n; i++) {
        model_outputs(z + i * MODEL_NX, u + i * MODEL_NU, p + i * MODEL_NP, y + i * MODEL_NY);
        model_update(z + i * MODEL_NX, u + i * MODEL_NU, p + i * MODEL_NP,
                     z_next + i * MODEL_NX);
    }
}
"""

F64 = npt.NDArray[np.float64]


@pytest.fixture(scope="module")
def harness(tmp_path_factory: pytest.TempPathFactory) -> ctypes.CDLL:
    """The controller core compiled with the build's flags plus the array loop."""
    tmp = tmp_path_factory.mktemp("ctrl-harness")
    write_controller_core(controller_model(), "{test}", tmp)
    (tmp / "harness.c").write_text(_HARNESS)
    lib = tmp / "harness.so"
    cmd = ["gcc", "-fPIC", "-shared", *CFLAGS, f"-I{tmp}", f"-I{paths.fmu_src_dir()}",
           *map(str, controller_sources()), str(tmp / "harness.c"), "-o", str(lib), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr
    dll = ctypes.CDLL(str(lib))
    dp = ctypes.POINTER(ctypes.c_double)
    dll.harness_sample.argtypes = [ctypes.c_int, dp, dp, dp, dp, dp]
    dll.harness_sample.restype = None
    return dll


def _random_parameters(rng: np.random.Generator) -> dict[str, float]:
    """A parameter set by FMU name: gains and limits over wide ranges, friction on or off."""
    u = rng.uniform
    p = {
        "goal.x_m": u(-20, 20), "goal.y_m": u(-20, 20),
        # a third of the goals face near +-180 deg, where beta and gamma wrap
        "goal.heading_deg": u(-180, 180) if rng.random() < 0.67
        else rng.choice([-1, 1]) * u(179.0, 180.0),
        "gains.K_ps": u(0, 2), "gains.K_is": u(0, 0.3), "gains.K_ptheta": u(0, 5),
        "gains.K_itheta": u(0, 1.5), "gains.K_pw": 0.0 if rng.random() < 0.1 else u(0, 15),
        "gains.K_iw": u(0, 60),
        "limits.v_max_mps": u(0.1, 2), "limits.omega_max_radps": u(0.1, 3),
        "limits.wheel_speed_max_radps": u(1, 20), "limits.torque_max_nm": u(0.5, 15),
        "params.r": u(0.05, 0.3), "params.L": u(0.1, 0.5),
        "params.b_f": 0.0 if rng.random() < 0.5 else u(0, 0.1),
        "params.tau_c": 0.0 if rng.random() < 0.5 else u(0, 0.5),
        "params.w_c": u(0.001, 0.1),
        "control_period_s": u(0.001, 0.05), "stop_radius_m": u(0.01, 0.2),
        "heading_tolerance_deg": u(0.1, 5),
    }
    return p


def _random_samples(rng: np.random.Generator, p: dict[str, float], n: int) -> tuple[F64, F64]:
    """``n`` states z and inputs u around the goal of ``p``: far, at the stop and exit radii,
    on the goal, headings near +-pi and unwrapped, previous angles on both sides of +-pi."""
    xd, yd, eps = p["goal.x_m"], p["goal.y_m"], p["stop_radius_m"]
    theta_d = math.radians(p["goal.heading_deg"])
    kind = rng.integers(0, 5, n)
    dist = np.select(
        [kind == 0, kind == 1, kind == 2, kind == 3],
        [rng.uniform(0, 40, n),  # anywhere
         eps * (0.5 + rng.normal(0, 1e-3, n)),  # at the alignment radius
         eps * (2.0 + rng.normal(0, 1e-3, n)),  # at the exit radius
         rng.uniform(0, 1.2 * eps, n)],  # inside the stop radius
        np.zeros(n))  # on the goal
    bearing = rng.uniform(-math.pi, math.pi, n)
    x = xd + dist * np.cos(bearing)
    y = yd + dist * np.sin(bearing)
    near = rng.random(n) < 0.5  # headings near the goal's (convergence test, alignment)
    theta = np.where(near, theta_d + rng.normal(0, 0.02, n), rng.uniform(-math.pi, math.pi, n))
    theta += 2 * math.pi * rng.integers(-3, 4, n) * (rng.random(n) < 0.2)  # unwrapped
    v = rng.normal(0, 0.015, n)
    omega = rng.normal(0, 0.03, n)
    omega_r = rng.uniform(-12, 12, n)
    omega_l = rng.uniform(-12, 12, n)
    u = np.column_stack([x, y, theta, v, omega, omega_r, omega_l])

    def angle() -> F64:  # previous gamma/beta: anywhere, or within the band of +-pi
        a = rng.uniform(-math.pi - 0.3, math.pi + 0.3, n)
        edge = rng.choice([-1.0, 1.0], n) * (math.pi - rng.uniform(-0.3, 0.3, n))
        return np.where(rng.random(n) < 0.5, a, edge)

    z = np.column_stack([rng.integers(0, 2, n).astype(float), rng.uniform(-1, 1, n),
                         rng.uniform(-2, 2, n), angle(), angle(), rng.uniform(-10, 10, n),
                         rng.uniform(-10, 10, n)])
    z[kind == 4, 0] = ALIGN  # on the goal: mostly aligning
    return z, u


def _python_reference(p: dict[str, float], z: F64, u: F64) -> tuple[F64, F64]:
    """The Python controller on each sample: outputs as the FMU lays them out, next states."""
    gains = Gains(**{f.name: p[f"gains.{f.name}"] for f in fields(Gains)})
    limits = Limits(**{f.name: p[f"limits.{f.name}"] for f in fields(Limits)})
    params = RobotParams(**{k: p[f"params.{k}"] for k in ("r", "L", "b_f", "tau_c", "w_c")})
    ctrl = PIController(Pose(p["goal.x_m"], p["goal.y_m"], math.radians(p["goal.heading_deg"])),
                      gains, limits, params, p["control_period_s"], p["stop_radius_m"])
    tol = math.radians(p["heading_tolerance_deg"])
    stab, right, left = ctrl.stabiliser, ctrl.right, ctrl.left
    assert not isinstance(stab, type(None))
    y = np.empty((len(z), len(SIGNAL_OUTPUTS) + 2))
    zn = np.empty_like(z)
    for k, (zk, uk) in enumerate(zip(z.tolist(), u.tolist(), strict=True)):
        (stab.phase, stab.i_s, stab.i_theta, stab.prev_gamma, stab.prev_beta,  # type: ignore[attr-defined]
         right.integral, left.integral) = (int(zk[0]), *zk[1:])
        x, yy, theta, v, omega, w_r, w_l = uk
        converged = stab.converged(x, yy, theta, v, omega, tol)
        y[k, :20] = ctrl.step(x, yy, theta, w_r, w_l)
        y[k, 20] = stab.phase  # type: ignore[attr-defined]
        y[k, 21] = converged
        zn[k] = (stab.phase, stab.i_s, stab.i_theta, stab.prev_gamma,  # type: ignore[attr-defined]
                 stab.prev_beta, right.integral, left.integral)  # type: ignore[attr-defined]
    return y, zn


def _c_core(dll: ctypes.CDLL, z: F64, u: F64, p: F64) -> tuple[F64, F64]:
    n = len(z)
    y = np.empty((n, len(SIGNAL_OUTPUTS) + 2))
    zn = np.empty_like(z)
    dp = ctypes.POINTER(ctypes.c_double)
    arrays = [np.ascontiguousarray(a) for a in (z, u, p)]
    dll.harness_sample(n, *(a.ctypes.data_as(dp) for a in arrays), y.ctypes.data_as(dp),
                       zn.ctypes.data_as(dp))
    return y, zn


@dataclass(frozen=True)
class Samples:
    """Random controller samples (z, u, p by row) and the Python reference's answers."""

    z: F64
    u: F64
    p: F64
    y: F64
    z_next: F64

    def assert_equal(self, y: F64, z_next: F64, what: str) -> None:
        """``y`` and ``z_next`` of another implementation agree with the Python's to 1e-12."""
        for col, name in enumerate((*SIGNAL_OUTPUTS, "phase", "converged")):
            np.testing.assert_allclose(y[:, col], self.y[:, col], rtol=1e-12, atol=1e-12,
                                       err_msg=f"{what}: {name}")
        for col, name in enumerate(STATES):
            np.testing.assert_allclose(z_next[:, col], self.z_next[:, col], rtol=1e-12,
                                       atol=1e-12, err_msg=f"{what}: next {name}")


@pytest.fixture(scope="module")
def samples() -> Samples:
    """100,000 random samples over 200 parameter sets, answered by the Python controller."""
    rng = np.random.default_rng(20260610)
    names = [v.name for v in controller_model().parameters]
    zs, us, ps, y_py, zn_py = [], [], [], [], []
    for _ in range(N_SETS):
        p = _random_parameters(rng)
        z, u = _random_samples(rng, p, N_PER_SET)
        y, zn = _python_reference(p, z, u)
        zs.append(z)
        us.append(u)
        ps.append(np.tile([p[n] for n in names], (N_PER_SET, 1)))
        y_py.append(y)
        zn_py.append(zn)
    return Samples(np.vstack(zs), np.vstack(us), np.vstack(ps), np.vstack(y_py),
                   np.vstack(zn_py))


def test_c_core_equals_the_python_controller_on_100000_random_samples(
        harness: ctypes.CDLL, samples: Samples) -> None:
    z_all, u_all, p_all, y_ref = samples.z, samples.u, samples.p, samples.y
    names = [v.name for v in controller_model().parameters]
    y_c, zn_c = _c_core(harness, z_all, u_all, p_all)
    samples.assert_equal(y_c, zn_c, "C on the host")

    assert len(z_all) >= 100_000

    # the samples reach every branch of the law (else the comparison proves little)
    out = {n: y_ref[:, i] for i, n in enumerate((*SIGNAL_OUTPUTS, "phase", "converged"))}
    p_col = {n: p_all[:, i] for i, n in enumerate(names)}
    switched_in = (z_all[:, 0] == 0) & (out["phase"] == 1)
    switched_out = (z_all[:, 0] == 1) & (out["phase"] == 0)
    coverage = {
        "enters alignment": switched_in.sum(),
        "leaves alignment": switched_out.sum(),
        "converged": (out["converged"] == 1).sum(),
        "beta clamped": (np.abs(out["beta"]) > math.pi / 3).sum(),
        "gamma beyond +-pi (hysteresis)": (np.abs(out["gamma"]) > math.pi).sum(),
        "u_s at v_max": (out["u_s"] == p_col["limits.v_max_mps"]).sum(),
        "u_s at 0 (forward only)": ((out["u_s"] == 0) & (out["phase"] == 0)).sum(),
        "u_theta saturated": (np.abs(out["u_theta"]) == p_col["limits.omega_max_radps"]).sum(),
        "wheel references scaled": (np.maximum(np.abs(out["omega_r_ref"]),
                                               np.abs(out["omega_l_ref"]))
                                    == p_col["limits.wheel_speed_max_radps"]).sum(),
        "torque saturated": (np.abs(out["tau_r"]) == p_col["limits.torque_max_nm"]).sum(),
        "on the goal (dr = 0)": (out["dr"] == 0).sum(),
    }
    thin = {k: int(v) for k, v in coverage.items() if v < 200}
    assert not thin, f"branches reached by fewer than 200 samples: {thin}"


_CROSS_MAIN = r"""
#include <stdio.h>
#include <stdlib.h>
#include "model.h"
/* test-only: read n and the rows of z, u, p from argv[1], write y and z_next to argv[2] */
int main(int argc, char **argv) {
    FILE *in, *out;
    int n, i;
    double *z, *u, *p, *y, *zn;
    if (argc != 3 || !(in = fopen(argv[1], "rb")) || fread(&n, sizeof n, 1, in) != 1) return 2;
    z = malloc(sizeof(double) * n * MODEL_NX); u = malloc(sizeof(double) * n * MODEL_NU);
    p = malloc(sizeof(double) * n * MODEL_NP); y = malloc(sizeof(double) * n * MODEL_NY);
    zn = malloc(sizeof(double) * n * MODEL_NX);
    if (fread(z, sizeof(double), (size_t)n * MODEL_NX, in) != (size_t)n * MODEL_NX ||
        fread(u, sizeof(double), (size_t)n * MODEL_NU, in) != (size_t)n * MODEL_NU ||
        fread(p, sizeof(double), (size_t)n * MODEL_NP, in) != (size_t)n * MODEL_NP) return 3;
    fclose(in);
    for (i = 0; i < n; i++) {
        model_outputs(z + i * MODEL_NX, u + i * MODEL_NU, p + i * MODEL_NP, y + i * MODEL_NY);
        model_update(z + i * MODEL_NX, u + i * MODEL_NU, p + i * MODEL_NP, zn + i * MODEL_NX);
    }
    if (!(out = fopen(argv[2], "wb"))) return 4;
    fwrite(y, sizeof(double), (size_t)n * MODEL_NY, out);
    fwrite(zn, sizeof(double), (size_t)n * MODEL_NX, out);
    return fclose(out) != 0;
}
"""


@pytest.mark.slow
def test_the_aarch64_binary_computes_the_same_law(tmp_path: Path, samples: Samples) -> None:
    """The controller core cross-compiled by the build's compiler (zig: clang, which fuses
    multiply-adds unless told not to) for aarch64 and run under qemu agrees with Python."""
    import sys

    pytest.importorskip("ziglang", reason="zig cross-compiles the non-host platforms")
    if shutil.which("qemu-aarch64") is None:
        pytest.skip("qemu-aarch64 (Debian qemu-user) runs the aarch64 binary")
    write_controller_core(controller_model(), "{test}", tmp_path)
    (tmp_path / "main.c").write_text(_CROSS_MAIN)
    exe = tmp_path / "harness-aarch64"
    cmd = [sys.executable, "-m", "ziglang", "cc", "-target", "aarch64-linux-musl", "-static",
           *CFLAGS, f"-I{tmp_path}", f"-I{paths.fmu_src_dir()}",
           *map(str, controller_sources()), str(tmp_path / "main.c"), "-o", str(exe), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr
    n = len(samples.z)
    data = tmp_path / "in.bin"
    data.write_bytes(np.int32(n).tobytes() + b"".join(
        np.ascontiguousarray(a).tobytes() for a in (samples.z, samples.u, samples.p)))
    result = tmp_path / "out.bin"
    run = subprocess.run(["qemu-aarch64", str(exe), str(data), str(result)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    raw = np.fromfile(result, dtype=np.float64)
    n_y = samples.y.shape[1]
    y = raw[:n * n_y].reshape(n, n_y)
    z_next = raw[n * n_y:].reshape(n, -1)
    samples.assert_equal(y, z_next, "C on aarch64")


def test_output_order_follows_the_log_columns() -> None:
    """The first 20 outputs are CONTROL_SIGNALS without their unit suffix, in order."""
    assert len(SIGNAL_OUTPUTS) == len(CONTROL_SIGNALS)
    for fmu_name, column in zip(SIGNAL_OUTPUTS, CONTROL_SIGNALS, strict=True):
        assert column.startswith(fmu_name + "_"), (fmu_name, column)
    model = controller_model()
    assert [v.name for v in model.inputs] == list(INPUTS)
    assert [v.name for v in model.outputs] == [*SIGNAL_OUTPUTS, "phase", "converged"]


def test_parameters_carry_the_scenario_names_and_defaults() -> None:
    from wmr.config.scenario import parse_scenario
    from wmr.core.runspec import (
        DEFAULT_HEADING_TOLERANCE_DEG,
        DEFAULT_PERIOD_S,
        DEFAULT_STOP_RADIUS_M,
    )

    start = {v.name: v.start for v in controller_model().parameters}
    expected = {f"gains.{k}": v for k, v in Gains().as_dict().items()}
    expected |= {f"limits.{k}": v for k, v in Limits().as_dict().items()}
    expected |= {f"params.{k}": getattr(RobotParams(), k) for k in ("r", "L", "b_f", "tau_c",
                                                                     "w_c")}
    expected |= {"control_period_s": DEFAULT_PERIOD_S, "stop_radius_m": DEFAULT_STOP_RADIUS_M,
                 "heading_tolerance_deg": DEFAULT_HEADING_TOLERANCE_DEG}
    for name, value in expected.items():
        assert start[name] == value, name
    assert {"goal.x_m", "goal.y_m", "goal.heading_deg"} <= set(start)
    # every parameter is a key a scenario file accepts, at the same dotted path
    table: dict[str, object] = {"start": [0.0, 0.0, 0.0], "goal": [1.0, 2.0, 3.0]}
    for name, value in start.items():
        section, _, key = name.rpartition(".")
        if section == "goal":
            continue
        target = table.setdefault(section, {}) if section else table
        assert isinstance(target, dict)
        target[key] = value
    run = parse_scenario(table).runs[0]
    assert run.gains == Gains() and run.limits == Limits()


@pytest.mark.parametrize("version", [2, 3])
def test_controller_fmus_pass_validation_and_declare_the_period(built: BuildResult,
                                                                     version: int) -> None:
    path = built.controllers[version]
    assert path.name == f"wmr_controller-fmi{version}.fmu"
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path), validate=True)  # the FMI XSD schemas
    assert md.coSimulation.modelIdentifier == "wmr_controller"
    assert md.coSimulation.canHandleVariableCommunicationStepSize is True  # on its grid
    assert md.defaultExperiment.stepSize == "0.01" or float(md.defaultExperiment.stepSize) == 0.01
    variables = {v.name: v for v in md.modelVariables}
    for name in INPUTS:
        assert variables[name].causality == "input"
    for name in (*SIGNAL_OUTPUTS, "phase", "converged"):
        assert variables[name].causality == "output"
        assert variables[name].variability == "discrete"
    assert variables["gains.K_ps"].causality == "parameter"
    assert variables["goal.heading_deg"].unit == "deg"


#: fmpy's native logger proxy (``fmpy.logging.addLoggerProxy``) keeps the LAST Python logger
#: given to ``instantiate_fmu`` in a process-wide variable, and ``fmpy.fmi2.defaultCallbacks``
#: goes through that proxy too: once such a logger is garbage-collected, the next FMI 2 message of
#: any instance in the process calls freed memory (a Bus error in a later test).  The callbacks
#: given to fmpy here therefore live as long as the process.
_FMPY_LOGGER_CALLBACKS: list[object] = []


def _simulate(path: Path, step_size: float, inputs: dict[str, float] | None = None
              ) -> tuple[int, list[str]]:
    """Drive the FMU one step through fmpy; return the doStep status and the log lines."""
    from fmpy import extract, instantiate_fmu

    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    messages: list[str] = []

    def logger(*args: object) -> None:
        messages.append(str(args[-1].decode() if isinstance(args[-1], bytes) else args[-1]))

    unzipdir = extract(str(path))
    fmu = instantiate_fmu(unzipdir, md, fmi_type="CoSimulation", logger=logger)
    _FMPY_LOGGER_CALLBACKS.append(getattr(fmu, "callbacks", None) or fmu.logMessage)
    setter = fmu.setReal if md.fmiVersion == "2.0" else fmu.setFloat64
    getter = fmu.getReal if md.fmiVersion == "2.0" else fmu.getFloat64
    status = 0
    try:
        if md.fmiVersion == "2.0":
            fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        try:
            if inputs:
                setter([vr[n] for n in inputs], list(inputs.values()))
            fmu.doStep(0.0, step_size)
        except Exception as exc:
            status = 3
            messages.append(f"raised {exc}")
        torques = getter([vr["tau_r"], vr["tau_l"]])
        assert all(math.isfinite(t) for t in torques)
    finally:
        fmu.freeInstance()
        shutil.rmtree(unzipdir, ignore_errors=True)
    return status, messages


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_measurements_give_an_error_and_no_nan_torque(
        built: BuildResult, version: int, bad: float) -> None:
    status, messages = _simulate(built.controllers[version], 0.01, {"x": 1.0, "theta": bad})
    assert status == 3
    assert any("theta" in m and "not a finite number" in m for m in messages), messages


# ---- the controller FMU in the master loop (wmr run --controller-fmu) ----


def _paths(spec: RunSpec, plant: FmuPlant, ctrl: FmuController | None) -> F64:
    """The run's rows (x, y, theta and every controller signal), recorded in memory."""
    rows = MemoryLog()
    result = run_closed_loop(spec, plant, sink=rows, controller=ctrl or SpecController())
    assert result.status == "converged", (spec.name, result.message)
    return rows.block


@pytest.mark.parametrize("scenario", ["fig9", "fig10"])
def test_every_paper_run_on_the_controller_fmu_follows_the_python_path(
        built: BuildResult, scenario: str) -> None:
    """Fig. 9 and Fig. 10: the closed loop with the C controller traces the Python one."""
    worst = 0.0
    with FmuPlant(built.fmus[3]) as plant, FmuController(built.controllers[3]) as ctrl:
        for spec in load_scenario(scenario).runs:
            ref = _paths(spec, plant, None)
            got = _paths(spec, plant, ctrl)
            assert got.shape == ref.shape, spec.name  # same number of steps: same stop
            pose = [COLUMN["x_m"], COLUMN["y_m"], COLUMN["theta_rad"]]
            worst = max(worst, float(np.max(np.abs(got[:, pose] - ref[:, pose]))))
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9, err_msg=spec.name)
    assert worst <= 1e-9


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_wmr_run_with_the_controller_fmu_writes_the_same_log(
        tmp_path: Path, built: BuildResult, capsys: pytest.CaptureFixture[str],
        fmi: str) -> None:
    py, fmu = tmp_path / "py.mcap", tmp_path / "fmu.mcap"
    assert main(["run", "--fmi", fmi, "--out", str(py)]) == 0
    assert main(["run", "--fmi", fmi, "--controller-fmu", "--out", str(fmu)]) == 0
    ref, got = read_run(py), read_run(fmu)
    with py.open("rb") as a, fmu.open("rb") as b:
        topics = [sorted(c.topic for c in make_reader(f).get_summary().channels.values())
                  for f in (a, b)]
    assert topics[0] == topics[1]
    assert ref.n_steps == got.n_steps
    np.testing.assert_array_equal(ref.t_s, got.t_s)
    for name in SIGNALS:
        np.testing.assert_allclose(got.signals[name], ref.signals[name], rtol=0, atol=1e-9,
                                   err_msg=name)
    assert got.metadata["run"]["controller_fmu_file"] == f"wmr_controller-fmi{fmi}.fmu"
    assert "controller_fmu_file" not in ref.metadata["run"]


def test_scenario_key_controller_fmu_and_its_errors(tmp_path: Path, built: BuildResult,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    text = ('start = [0.0, 0.0, 0.0]\ngoal = [2.0, 1.0, 30.0]\n'
            'controller_fmu = "{}"\n')
    good = tmp_path / "good.toml"
    good.write_text(text.format(built.controllers[3]))
    assert load_scenario(good).runs[0].controller_fmu == str(built.controllers[3])
    log = tmp_path / "good.mcap"
    assert main(["run", str(good), "--out", str(log)]) == 0
    assert read_run(log).metadata["run"]["controller_fmu_file"] == "wmr_controller-fmi3.fmu"
    flag = tmp_path / "flag.toml"
    flag.write_text(text.replace('"{}"', "true"))
    assert load_scenario(flag).runs[0].controller_fmu == ""

    missing = tmp_path / "missing.toml"
    missing.write_text(text.format("nowhere.fmu"))
    capsys.readouterr()  # the good run's lines (a host build's, when none was made before)
    assert main(["run", str(missing), "--out", str(tmp_path / "m.mcap")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--controller-fmu" in err[0] and "nowhere.fmu" in err[0]
    peer = tmp_path / "peer.toml"
    peer.write_text(text.replace('"{}"', "true") + 'controller = "astolfi"\n')
    with pytest.raises(ConfigError, match="controller_fmu"):
        load_scenario(peer)
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('"{}"', "3"))
    with pytest.raises(ConfigError, match="controller_fmu: must be true, false or a path"):
        load_scenario(bad)


def test_a_nan_wheel_speed_fails_the_run_with_the_fmu_error(built: BuildResult) -> None:
    spec = load_scenario("fig11").runs[0]
    with FmuController(built.controllers[3]) as ctrl:
        ctrl.configure(spec)
        ctrl.stabiliser.converged(0.0, 0.0, 0.0, 0.0, 0.0, spec.heading_tolerance_rad)
        sig = ctrl.step(0.0, 0.0, 0.0, 0.0, 0.0)
        assert all(math.isfinite(s) for s in sig)
        with pytest.raises(FmuError, match=r"fmi3SetFloat64 returned Error .*omega_r = nan"):
            ctrl.step(0.0, 0.0, 0.0, math.nan, 0.0)


@pytest.mark.parametrize("version", [2, 3])
def test_the_controller_fmu_is_held_and_logs_like_the_robot(
        built: BuildResult, version: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capfd: pytest.CaptureFixture[str]) -> None:
    """The controller FMU's instance is an FmuSlave, as the robot's: its folder is locked while
    it lives (a cleaner leaves it), and its log messages go to stderr, never to stdout (where
    ``--json`` puts its line; fmpy's default logger prints there; checked on FMI 3)."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    spec = load_scenario("fig11").runs[0]
    with FmuController(built.controllers[version]) as ctrl:
        [folder] = tmp_path.glob("wmr-fmu-*")
        assert remove_stale_folders(tmp_path) == [] and folder.is_dir()
        ctrl.configure(spec)
        ctrl.stabiliser.converged(0.0, 0.0, 0.0, 0.0, 0.0, spec.heading_tolerance_rad)
        with pytest.raises(FmuError, match="returned Error"):
            ctrl.step(0.0, 0.0, 0.0, math.nan, 0.0)
    assert not folder.exists()
    if version == 2:
        # FMI 2 messages pass fmpy's logger proxy, one per process: after an fmpy
        # simulate_fmu in the same process (other tests) they go to its logger, not ours
        return
    out, err = capfd.readouterr()
    assert "[ERROR]" in err and "omega_r" in err, err
    assert "[ERROR]" not in out, out


def test_the_variables_table_of_docs_control_md_matches_the_code() -> None:
    text = (Path(__file__).parent.parent / "docs" / "control.md").read_text()
    section = text.split("## The controller FMU", 1)[1].split("\n## ", 1)[0]
    rows = [line.split("|")[1:-1] for line in section.splitlines()
            if line.startswith("| `")]
    documented = [(c[0].strip().strip("`"), c[1].strip(), c[2].strip(), c[3].strip())
                  for c in rows]
    expected = [(v.name, v.kind, v.unit or "1", "" if v.kind == "output" else repr(v.start))
                for v in controller_model().variables]
    assert documented == expected


def test_a_batch_with_the_controller_fmu_key_logs_the_python_paths(tmp_path: Path,
                                                                   built: BuildResult) -> None:
    from wmr.apps.batch import BatchOptions, load_batch, run_batch

    spec = ('name = "b"\nstart = [0.0, 0.0, 0.0]\ngoal = [1.5, 0.5, 20.0]\n{key}'
            '[grid]\ngoal = [[1.5, 0.5, 20.0], [-1.0, 1.0, 90.0]]\n')
    logs = {}
    for label, key in (("py", ""), ("fmu", "controller_fmu = true\n")):
        path = tmp_path / f"{label}.toml"
        path.write_text(spec.format(key=key))
        batch = load_batch(path)
        out = tmp_path / label
        result = run_batch(batch, out, BatchOptions(workers=1, fmu_path=built.fmus[3]),
                           progress=False)
        assert result.counts["converged"] == 2 == result.total
        logs[label] = [read_run(out / "runs" / f"{r.run_id}.mcap") for r in batch.runs]
    for ref, got in zip(logs["py"], logs["fmu"], strict=True):
        assert got.metadata["run"]["controller_fmu_file"] == "wmr_controller-fmi3.fmu"
        assert ref.n_steps == got.n_steps
        for name in SIGNALS:
            np.testing.assert_allclose(got.signals[name], ref.signals[name], rtol=0,
                                       atol=1e-9, err_msg=name)


def test_run_ids_of_python_runs_do_not_move_and_fmu_runs_get_their_own() -> None:
    """A batch folder written before the controller_fmu key resumes without rerunning."""
    import hashlib
    import json
    from dataclasses import asdict, replace

    from wmr.apps.batch.spec import _canonical, spec_digest

    spec = load_scenario("fig11").runs[0]
    before = asdict(spec)
    del before["controller_fmu"], before["sensors"]  # the fields of a run before either key
    text = json.dumps(_canonical(before), sort_keys=True, separators=(",", ":"))
    assert spec_digest(spec) == hashlib.sha256(text.encode()).hexdigest()
    assert spec_digest(replace(spec, controller_fmu="")) != spec_digest(spec)


def test_the_convergence_test_refuses_a_tolerance_the_fmu_was_not_given(
        built: BuildResult) -> None:
    spec = load_scenario("fig11").runs[0]
    with FmuController(built.controllers[2]) as ctrl:
        ctrl.configure(spec)
        assert ctrl.stabiliser.converged(0.0, 0.0, 0.0, 0.0, 0.0,
                                         spec.heading_tolerance_rad) is False
        with pytest.raises(ConfigError, match="heading_tolerance_deg"):
            ctrl.stabiliser.converged(0.0, 0.0, 0.0, 0.0, 0.0, 2 * spec.heading_tolerance_rad)


def test_a_robot_fmu_or_a_peer_controller_is_refused_in_one_line(
        tmp_path: Path, built: BuildResult, capsys: pytest.CaptureFixture[str]) -> None:
    from dataclasses import replace

    with pytest.raises(FmuError, match=r"not a controller FMU .*wrong: x \(output\)"):
        FmuController(built.fmus[3])
    code = main(["run", "--controller-fmu", str(built.fmus[3]),
                 "--out", str(tmp_path / "x.mcap")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "not a controller FMU" in err[0]
    spec = replace(load_scenario("fig11").runs[0], controller="astolfi")
    with FmuController(built.controllers[3]) as ctrl, \
            pytest.raises(ConfigError, match=r"controller_fmu.*astolfi"):
        ctrl.configure(spec)


def test_with_sensors_the_controller_fmu_gets_the_estimate_and_logs_the_same(
        tmp_path: Path, built: BuildResult, capsys: pytest.CaptureFixture[str]) -> None:
    """The master feeds either controller the EKF's estimate: same rows with sensors on."""
    py, fmu = tmp_path / "py.mcap", tmp_path / "fmu.mcap"
    assert main(["run", "--sensors", "gps", "--out", str(py)]) == 0
    assert main(["run", "--sensors", "gps", "--controller-fmu", "--out", str(fmu)]) == 0
    ref, got = read_run(py), read_run(fmu)
    assert ref.n_steps == got.n_steps
    for name in SIGNALS:
        np.testing.assert_allclose(got.signals[name], ref.signals[name], rtol=0, atol=1e-9,
                                   err_msg=name)


@pytest.mark.parametrize("version", [2, 3])
def test_model_exchange_is_refused_and_not_declared(built: BuildResult, version: int) -> None:
    """The discrete states are no continuous states: no Model Exchange, no derivatives."""
    from fmpy import extract
    from fmpy.fmi2 import FMU2Model
    from fmpy.fmi3 import FMU3Model

    path = built.controllers[version]
    md = read_model_description(str(path))
    assert md.modelExchange is None
    assert md.coSimulation.providesDirectionalDerivative is False
    unzipdir = extract(str(path))
    messages: list[str] = []

    def logger(*args: object) -> None:
        message = args[-1]
        messages.append(message.decode() if isinstance(message, bytes) else str(message))

    try:
        if version == 2:
            from wmr.adapters.fmi.slave import fmi2_callbacks

            callbacks = fmi2_callbacks(logger)
            fmu2 = FMU2Model(guid=md.guid, unzipDirectory=unzipdir,
                             modelIdentifier="wmr_controller", instanceName="me")
            with pytest.raises(Exception, match="Failed to instantiate"):
                fmu2.instantiate(callbacks=callbacks)
        else:
            fmu3 = FMU3Model(guid=md.guid, unzipDirectory=unzipdir,
                             modelIdentifier="wmr_controller", instanceName="me")
            with pytest.raises(Exception, match="Failed to instantiate"):
                fmu3.instantiate(logMessage=logger)
        assert any("Model Exchange is not provided" in m for m in messages), messages
    finally:
        shutil.rmtree(unzipdir, ignore_errors=True)


@pytest.mark.parametrize("option", [["--controller-fmu", "nowhere.fmu"],
                                    ["--map", "nowhere.toml"]])
def test_a_missing_input_file_is_refused_before_the_fmus_are_built(
        option: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A missing controller FMU or map was named only after a build of the FMUs (seconds on
    a fresh cache, and a screenful of build lines before the one that mattered)."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("WMR_CACHE_DIR", str(cache))
    assert main(["run", "fig11", *option, "--out", str(tmp_path / "x.mcap")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nowhere" in err[0], err
    assert not cache.exists() or not any(cache.rglob("*.fmu"))

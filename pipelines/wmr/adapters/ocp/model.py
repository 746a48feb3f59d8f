"""The robot model of the OCP: the Modelica model's explicit ODE as CasADi functions, RK4
integration and :func:`simulate`."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np
import numpy.typing as npt

from wmr.adapters.ocp.problem import DEFAULT_PARAMS, DEFAULT_RK_SUBSTEPS, FloatArray
from wmr.core.plant import Pose, RobotParams
from wmr.infra.errors import ConfigError


@dataclass(frozen=True)
class _Model:
    """The flattened Modelica model and the index maps the OCP needs."""

    ode: ca.Function  # (x, u, p) -> xdot
    out: ca.Function  # (x, u, p) -> y
    init: ca.Function  # (p) -> x0
    state_names: tuple[str, ...]
    param_names: tuple[str, ...]
    param_starts: tuple[float, ...]
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]

    def sx(self, name: str) -> int:
        return self.state_names.index(name)

    def oy(self, name: str) -> int:
        return self.output_names.index(name)

    def wheel_states(self) -> tuple[int, ...]:
        return tuple(i for i, n in enumerate(self.state_names)
                     if n not in ("x", "y", "theta", "v", "omega"))

    def param_vector(self, params: RobotParams, start: Pose) -> FloatArray:
        """The model's parameter vector for ``params`` and a start at rest at ``start``."""
        values = params.as_dict()
        values.update(x0=start.x_m, y0=start.y_m, theta0=start.heading_rad, v0=0.0, omega0=0.0)
        return np.array([values.get(n, s) for n, s in zip(self.param_names, self.param_starts,
                                                          strict=True)], dtype=float)


@lru_cache(maxsize=1)
def _model() -> _Model:
    """Flatten ``modelica/WMR`` once per process (about 0.3 s)."""
    from wmr.build.flatten import flatten
    from wmr.infra import paths

    flat = flatten(paths.modelica_dir())
    model = _Model(ode=flat.ode, out=flat.out, init=flat.init, state_names=tuple(flat.state_names),
                   param_names=tuple(v.name for v in flat.parameters),
                   param_starts=tuple(float(v.start) for v in flat.parameters),
                   output_names=tuple(v.name for v in flat.outputs),
                   input_names=tuple(v.name for v in flat.inputs))
    needed = {"x", "y", "theta", "v", "omega"}
    if not needed <= set(model.state_names):
        raise ConfigError("modelica", f"the model's states {model.state_names} lack "
                          f"{sorted(needed - set(model.state_names))}")
    if model.input_names != ("tau_r", "tau_l"):
        raise ConfigError("modelica", f"the model's inputs are {model.input_names}, "
                          "expected (tau_r, tau_l)")
    return model


@lru_cache(maxsize=8)
def _rk4_function(substeps: int) -> ca.Function:
    """``(x, u, p, h) -> x(h)``: ``substeps`` classical RK4 steps of the model's ODE."""
    m = _model()
    nx, nu, npar = m.ode.size1_in(0), m.ode.size1_in(1), m.ode.size1_in(2)
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", nu)
    p = ca.SX.sym("p", npar)
    h = ca.SX.sym("h")
    dt = h / substeps
    xk = x
    for _ in range(substeps):
        k1 = m.ode(xk, u, p)
        k2 = m.ode(xk + dt / 2 * k1, u, p)
        k3 = m.ode(xk + dt / 2 * k2, u, p)
        k4 = m.ode(xk + dt * k3, u, p)
        xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("wmr_rk4", [x, u, p, h], [xk], ["x", "u", "p", "h"], ["xf"])


def simulate(start: Pose, torques_nm: npt.ArrayLike, interval_s: float,
             params: RobotParams = DEFAULT_PARAMS, rk_substeps: int = DEFAULT_RK_SUBSTEPS
             ) -> dict[str, FloatArray]:
    """Integrate the model from rest at ``start`` with the OCP's own RK4 integrator.

    Parameters
    ----------
    start
        Initial pose (m, rad); the robot starts at rest.
    torques_nm
        (K, 2) array of (tau_r, tau_l) in N.m, each held for ``interval_s``.
    interval_s
        Length of one torque interval, s.
    params
        Robot parameters.
    rk_substeps
        RK4 steps per interval.

    Returns
    -------
    dict
        State name -> (K + 1,) array at the interval boundaries (SI units).
    """
    m = _model()
    u = np.asarray(torques_nm, dtype=float).reshape(-1, 2)
    p = m.param_vector(params, start)
    x = np.asarray(_initial_state(start, params)).ravel()
    f = _rk4_function(int(rk_substeps))
    xs = [x]
    for k in range(u.shape[0]):
        x = np.asarray(f(x, u[k], p, interval_s)).ravel()
        xs.append(x)
    arr = np.array(xs)
    return {n: arr[:, i].copy() for i, n in enumerate(m.state_names)}


def _initial_state(start: Pose, params: RobotParams) -> FloatArray:
    """The model's own initial state (its ``init`` function) for a start at rest."""
    m = _model()
    return np.asarray(m.init(m.param_vector(params, start)), dtype=float).ravel()

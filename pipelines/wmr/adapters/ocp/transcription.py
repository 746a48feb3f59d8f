"""The OCP's transcription: direct multiple shooting as one IPOPT NLP per
``(n_intervals, rk_substeps)`` and process, and one classified IPOPT run."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np

from wmr.adapters.ocp.model import _model, _rk4_function
from wmr.adapters.ocp.problem import (
    _IPOPT_INFEASIBLE,
    _IPOPT_SOLVED,
    FAILED_ADVICE,
    FloatArray,
    OptimalProblem,
    Status,
)
from wmr.adapters.ocp.result import OptimalResult, _integrals
from wmr.adapters.ocp.warmstart import _Guess

#: Longest silence of a solve, s: IPOPT's iteration, the final time and the objective are
#: reported at least this often to the ``progress`` of :func:`wmr.adapters.ocp.solve_optimal`.
PROGRESS_INTERVAL_S = 5.0


class _IterationReport(ca.Callback):
    """IPOPT's ``iteration_callback``: a line to ``receiver`` every :data:`PROGRESS_INTERVAL_S`
    of a solve (a failing one grinds for up to ``max_cpu_time_s``).  One per NLP, which is
    cached, so the receiver is set for each solve by :func:`_solve_nlp`."""

    def __init__(self, n_w: int, n_g: int) -> None:
        ca.Callback.__init__(self)
        self.n_w, self.n_g = n_w, n_g
        self.receiver: Callable[[str], None] | None = None
        self.iteration = 0
        self.t0 = self.last = 0.0
        self.construct("wmr_ocp_progress", {})

    def start(self, receiver: Callable[[str], None] | None) -> None:
        self.receiver = receiver
        self.iteration = 0
        self.t0 = self.last = time.monotonic()

    def get_n_in(self) -> int:
        return int(ca.nlpsol_n_out())

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return str(ca.nlpsol_out(i))

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.n_w)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.n_g)
        return ca.Sparsity(0, 0)

    def eval(self, arg: list[ca.DM]) -> list[int]:
        self.iteration += 1
        now = time.monotonic()
        if self.receiver is not None and now - self.last >= PROGRESS_INTERVAL_S:
            self.last = now
            w = arg[ca.nlpsol_out().index("x")]
            f = float(arg[ca.nlpsol_out().index("f")])
            self.receiver(f"IPOPT: iteration {self.iteration} ({now - self.t0:.0f} s), "
                          f"T = {float(w[-1]):.3f} s, objective {f:.4g}")
        return [0]


@dataclass(frozen=True)
class _Nlp:
    solver: ca.Function
    report: _IterationReport
    n: int
    nx: int
    nu: int
    n_x: int  # number of state variables in w
    n_u: int
    n_g_dyn: int


def _nlp_built(n: int, substeps: int, max_iter: int, max_cpu_time_s: float) -> bool:
    """Whether :func:`_nlp` has these arguments cached (a new NLP takes seconds to build)."""
    return any(key == (n, substeps, max_iter, max_cpu_time_s) for key in _BUILT)


_BUILT: list[tuple[int, int, int, float]] = []


@lru_cache(maxsize=16)
def _nlp(n: int, substeps: int, max_iter: int, max_cpu_time_s: float) -> _Nlp:
    r"""Build (once) the multiple-shooting NLP on ``n`` intervals.

    Decision vector ``w = [vec(X) (nx (n+1)), vec(U) (2 n), T]``; NLP parameters
    ``[p (model), theta_d, w_T, w_E]``; objective :math:`w_T T + w_E h \sum_k |u_k|^2`.
    Constraints ``g``: continuity (``nx n``), :math:`\sin(\theta_N - \theta_d) = 0`,
    :math:`\cos(\theta_N - \theta_d) \ge 0`, wheel speeds at every node (``2 (n+1)``).
    Everything else (start, goal position, rest at the end, torque and speed limits, T range)
    is a variable bound.
    """
    m = _model()
    nx, nu, npar = m.ode.size1_in(0), m.ode.size1_in(1), m.ode.size1_in(2)
    X = ca.MX.sym("X", nx, n + 1)
    U = ca.MX.sym("U", nu, n)
    T = ca.MX.sym("T")
    P = ca.MX.sym("P", npar + 3)
    p, theta_d, w_t, w_e = P[:npar], P[npar], P[npar + 1], P[npar + 2]
    h = T / n
    step = _rk4_function(substeps).map(n, "serial")
    x_next = step(X[:, :n], U, ca.repmat(p, 1, n), ca.repmat(h, 1, n))
    dyn = ca.vec(x_next - X[:, 1:])
    dth = X[m.sx("theta"), n] - theta_d
    u_nodes = ca.horzcat(U, U[:, n - 1])
    y = m.out.map(n + 1, "serial")(X, u_nodes, ca.repmat(p, 1, n + 1))
    wheels = ca.vertcat(ca.vec(y[m.oy("omega_r"), :]), ca.vec(y[m.oy("omega_l"), :]))
    g = ca.vertcat(dyn, ca.sin(dth), ca.cos(dth), wheels)
    J = w_t * T + w_e * h * ca.sumsqr(U)
    w = ca.vertcat(ca.vec(X), ca.vec(U), T)
    report = _IterationReport(w.numel(), g.numel())
    opts: dict[str, Any] = {
        "iteration_callback": report,
        "expand": True,
        "print_time": False,
        # IPOPT recovers from a NaN in a trial step by itself; CasADi's warning per NaN
        # (dozens for a far goal) only buries the one line of the result
        "show_eval_warnings": False,
        "error_on_fail": False,
        "ipopt": {"print_level": 0, "sb": "yes", "max_iter": max_iter,
                  "max_cpu_time": max_cpu_time_s, "tol": 1e-8,
                  "acceptable_tol": 1e-6, "acceptable_iter": 10},
    }
    solver = ca.nlpsol("wmr_ocp", "ipopt", {"x": w, "p": P, "f": J, "g": g}, opts)
    _BUILT.append((n, substeps, max_iter, max_cpu_time_s))
    return _Nlp(solver, report, n, nx, nu, nx * (n + 1), nu * n, nx * n)


def _solve_nlp(nlp: _Nlp, guess: _Guess,
               bounds: tuple[FloatArray, FloatArray, FloatArray, FloatArray], pn: FloatArray,
               problem: OptimalProblem, rk_substeps: int,
               progress: Callable[[str], None] | None = None) -> OptimalResult:
    """One IPOPT run of ``problem`` from ``guess`` within ``bounds`` (``lbx, ubx, lbg, ubg``)
    and with the NLP's parameters ``pn``, classified; ``progress`` hears of it while it
    runs."""
    lbx, ubx, lbg, ubg = bounds
    start, goal, params = problem.start, problem.goal, problem.params
    m = _model()
    n, nx = nlp.n, nlp.nx
    w0 = np.clip(guess.w0, lbx, ubx)
    t0 = time.perf_counter()
    nlp.report.start(progress)
    try:
        sol = nlp.solver(x0=w0, p=pn, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    finally:
        nlp.report.start(None)
    solve_time = time.perf_counter() - t0
    stats = nlp.solver.stats()
    ret = str(stats.get("return_status", "unknown"))
    iters = int(stats.get("iter_count", -1))
    w = np.asarray(sol["x"]).ravel()
    xs = w[:nlp.n_x].reshape(nx, n + 1, order="F")
    us = w[nlp.n_x:nlp.n_x + nlp.n_u].reshape(2, n, order="F").T.copy()
    T = float(w[-1])
    g = np.asarray(sol["g"]).ravel()
    viol = float(max(np.max(lbg - g), np.max(g - ubg), 0.0))
    if ret in _IPOPT_SOLVED:
        status: Status = "solved"
        message = f"IPOPT: {ret} in {iters} iterations"
    elif ret in _IPOPT_INFEASIBLE:
        status = "infeasible"
        message = (f"IPOPT: {ret}: no trajectory meets the limits and the goal "
                   f"(constraint violation {viol:.3g}); relax the limits"
                   + (" or give a longer final_time_s" if problem.final_time_s is not None
                      else ""))
    else:
        status = "failed"
        message = (f"IPOPT: {ret} after {iters} iterations (constraint violation {viol:.3g}); "
                   + FAILED_ADVICE)
    length, work, wmax, miss = _integrals(start, goal, params, us, T / n, rk_substeps)
    effort = float(T / n * np.sum(us**2))
    return OptimalResult(
        status=status, message=message, objective=problem.objective, start=start, goal=goal,
        params=params, limits=problem.limits, t_s=np.linspace(0.0, T, n + 1),
        states={nm: xs[i].copy() for i, nm in enumerate(m.state_names)}, torques=us,
        final_time_s=T if status == "solved" else math.nan,
        path_length_m=length, energy_positive_j=work, effort_N2m2s=effort, solve_time_s=solve_time,
        iterations=iters, rk_substeps=rk_substeps, return_status=ret,
        max_wheel_speed_radps=wmax, rollout_error_m=miss, extra={"constraint_violation": viol,
                                           "guess_final_time_s": guess.final_time_s})


# ----------------------------------------------------------------------------------------------

"""The paper's PI stabiliser compiled into the C stepper: the run's own law at the speed of C.

:class:`CompiledLawController` is the :class:`~wmr.core.control.from_spec.SpecController` of
``wmr run`` and ``wmr batch`` (the controller of every run without ``controller_fmu``).  For a
run of the paper's law (``controller = "pi"``) without sensors on an FMU plant with the C
stepper, it hands the loop whole blocks of the closed loop in one C call each
(``wmr_law_loop`` in ``fmu/src/stepper/wmr_stepper.c``): the law there is the controller FMU's
own core (``fmu/src/controller/controller.c``), operation for operation the Python law of
:mod:`wmr.core.control`, with Python's ``math.hypot`` algorithm and the run's goal heading and
heading tolerance in the Python run's own radians, so the rows, the log and the result are the
bits of the Python law (``tests/test_fast_path.py``).  Any other run (a peer controller,
sensors, a plant without the stepper) runs the Python law, exactly as
:class:`SpecController` does.

Before its first use in a process, the compiled law is checked against the Python law on a
fixed set of states (:func:`compiled_law_agrees`); a library that disagrees in any bit (another
Python's ``math.hypot``, another libm) is never used, and the runs fall back to the Python law.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable
from functools import partial
from typing import Any, Final, cast

import numpy as np
import numpy.typing as npt

from wmr.adapters.fmi.controller import controller_parameters
from wmr.adapters.stepper import FmuCall, LawCall, LoopState, load_stepper
from wmr.build.controller_interface import SIGNAL_OUTPUTS, controller_model
from wmr.core.control.from_spec import SpecController
from wmr.core.runspec import RunSpec
from wmr.infra.errors import FmuError

#: The controller FMU's parameter names, in the order of its parameter vector.
_PARAMETERS: Final = tuple(v.name for v in controller_model().parameters)
_N_SIG: Final = len(SIGNAL_OUTPUTS)
#: Per stepper library (by its path): the library and its law's number of discrete states,
#: once bound and checked; None when it has no law or disagrees.
_CHECKED: dict[str, tuple[Any, int] | None] = {}


def _bind(lib: Any) -> tuple[int, int, int, int] | None:
    """Declare the law's functions on ``lib``; its sizes ``(np, nu, ny, nx)``, or None for a
    stepper built without the law."""
    try:
        sizes = lib.wmr_law_sizes
        ptr = ctypes.POINTER
        lib.wmr_law_loop.argtypes = [ptr(FmuCall), ptr(LawCall), ptr(LoopState)]
        lib.wmr_law_loop.restype = ctypes.c_int
        lib.wmr_law_sample.argtypes = [ptr(LawCall), *[ctypes.c_void_p] * 3]
        lib.wmr_law_sample.restype = None
        lib.wmr_law_hypot.argtypes = [ctypes.c_double, ctypes.c_double]
        lib.wmr_law_hypot.restype = ctypes.c_double
    except AttributeError:
        return None
    n = [ctypes.c_int() for _ in range(4)]
    sizes(*(ctypes.byref(v) for v in n))
    return n[0].value, n[1].value, n[2].value, n[3].value


def _checked() -> tuple[Any, int] | None:
    """The stepper with the compiled law and its number of discrete states, bound and checked
    against the Python law once per library; None when there is none or it disagrees."""
    lib = load_stepper(build=False)
    if lib is None:
        return None
    key = str(lib._name)
    if key not in _CHECKED:
        sizes = _bind(lib)
        ok = (sizes is not None and sizes[0] == len(_PARAMETERS) and sizes[2] >= _N_SIG + 2
              and compiled_law_agrees(lib))
        _CHECKED[key] = (lib, sizes[3]) if ok and sizes is not None else None
    return _CHECKED[key]


def law_library() -> Any:
    """The C stepper with the compiled law, checked against the Python law; None when there
    is none or it disagrees (then the runs take the Python law)."""
    found = _checked()
    return None if found is None else found[0]


def parameter_vector(spec: RunSpec) -> npt.NDArray[np.float64]:
    """The controller FMU's parameters of ``spec`` in its parameter order."""
    values = controller_parameters(spec)
    missing = [n for n in _PARAMETERS if n not in values]
    if missing:  # the two descriptions drifted apart: a build error, not a user's
        raise FmuError(f"the compiled law lacks the run's value of {', '.join(missing)}")
    return np.array([values[n] for n in _PARAMETERS], dtype=np.float64)


class _Law:
    """The arrays of one configured run of the compiled law (kept alive with its struct)."""

    def __init__(self, spec: RunSpec, n_states: int) -> None:
        self.p = parameter_vector(spec)
        self.z = np.zeros(n_states, dtype=np.float64)  # PointStabiliser.reset, WheelServo.reset
        self.call = LawCall(self.p.ctypes.data, self.z.ctypes.data, spec.goal.heading_rad,
                            spec.heading_tolerance_rad)


class CompiledLawController(SpecController):
    """:class:`SpecController` whose paper PI runs in the C stepper when it can (see the
    module's docstring); one instance serves any number of runs."""

    def __init__(self) -> None:
        super().__init__()
        self._law: _Law | None = None

    def configure(self, spec: RunSpec) -> None:
        """Build the Python law of ``spec`` (as :class:`SpecController`), and the compiled
        law's run when the run is the paper's law without sensors."""
        super().configure(spec)
        self._law = None
        self.stepper_kind = "servo"
        if spec.controller == "pi" and not spec.controller_gains and spec.sensors is None:
            found = _checked()
            if found is not None:
                self._law = _Law(spec, found[1])
                self.stepper_kind = "blocks"

    def block_loop(self, lib: Any, plant_call: FmuCall, state: LoopState) -> Callable[[], int]:
        """The C call that runs the closed loop until the block is full or the run ends."""
        if self._law is None:
            raise RuntimeError("CompiledLawController.block_loop for a run of the Python law")
        return partial(lib.wmr_law_loop, ctypes.byref(plant_call), ctypes.byref(self._law.call),
                       ctypes.byref(state))

    def set_clock(self, n: int) -> None:
        """Nothing to keep: the compiled law has no clock of its own."""

    def raise_step_error(self, code: int) -> None:
        """The compiled law makes no FMI call; a code here is the stepper's own error."""
        raise FmuError(f"the C stepper's compiled law stopped with code {code}")


def compiled_law_agrees(lib: Any, n_states: int = 200, seed: int = 20261124) -> bool:
    """Whether the compiled law gives the Python law's bits on ``n_states`` random states.

    Each state: a random goal and gains, a pose, speeds and a law state drawn near the goal
    and far from it, in both phases, across the angle wrap; the sample's every output and
    next state must equal the Python law's, and ``wmr_law_hypot`` must equal ``math.hypot``
    on the same distances and on pairs of wide exponent range.
    """
    from wmr.core.control import Gains, Limits, PIController
    from wmr.core.control.stabiliser import ALIGN, APPROACH, PointStabiliser
    from wmr.core.plant import Pose, RobotParams

    sizes = _bind(lib)
    if sizes is None:
        return False
    _, n_u, n_y, n_x = sizes
    rng = np.random.default_rng(seed)
    a = rng.normal(size=512) * 10.0 ** rng.integers(-12, 12, 512)
    b = rng.normal(size=512) * 10.0 ** rng.integers(-12, 12, 512)
    if any(lib.wmr_law_hypot(x, y) != math.hypot(x, y) for x, y in zip(a.tolist(), b.tolist(),
                                                                       strict=True)):
        return False
    u = np.zeros(n_u)
    y = np.zeros(n_y)
    z_next = np.zeros(n_x)
    for _ in range(n_states // 40):
        gx, gy = rng.uniform(-20, 20, 2).tolist()
        goal = Pose(gx, gy, float(rng.uniform(-math.pi, math.pi)))
        gains = Gains(**{k: float(v * rng.uniform(0.5, 2.0))
                         for k, v in Gains().as_dict().items()})
        params = RobotParams(tau_c=float(rng.choice([0.0, 0.3])), b_f=float(rng.choice([0.0, 0.1])))
        spec = RunSpec(name="check", start=Pose(0.0, 0.0, 0.0), goal=goal, params=params,
                       gains=gains, limits=Limits(), period_s=0.01,
                       stop_radius_m=float(rng.choice([0.05, 0.2])))
        law = _Law(spec, n_x)
        for _ in range(40):
            py = PIController(goal, gains, Limits(), params, spec.period_s, spec.stop_radius_m)
            near = rng.random() < 0.5
            scale = spec.stop_radius_m * 3 if near else 15.0
            x, yy = (goal.x_m + rng.uniform(-scale, scale), goal.y_m + rng.uniform(-scale, scale))
            theta = float(rng.uniform(-4.0, 4.0))
            v, omega = rng.uniform(-0.02, 0.02, 2).tolist()
            w_r, w_l = rng.uniform(-10, 10, 2).tolist()
            st = cast(PointStabiliser, py.stabiliser)
            st.phase = ALIGN if near and rng.random() < 0.7 else APPROACH
            st.i_s, st.i_theta = rng.uniform(-0.5, 0.5, 2).tolist()
            st.prev_gamma, st.prev_beta = rng.uniform(-4.0, 4.0, 2).tolist()
            py.right.integral, py.left.integral = rng.uniform(-3, 3, 2).tolist()
            law.z[:] = (float(st.phase), st.i_s, st.i_theta, st.prev_gamma, st.prev_beta,
                        py.right.integral, py.left.integral)
            u[:] = (x, yy, theta, v, omega, w_r, w_l)
            lib.wmr_law_sample(ctypes.byref(law.call), u.ctypes.data, y.ctypes.data,
                               z_next.ctypes.data)
            converged = st.converged(x, yy, theta, v, omega, spec.heading_tolerance_rad)
            sig = py.step(x, yy, theta, w_r, w_l)
            want_z = (float(st.phase), st.i_s, st.i_theta, st.prev_gamma, st.prev_beta,
                      py.right.integral, py.left.integral)
            if (y[:_N_SIG].tolist() != list(sig) or bool(y[-1]) != converged
                    or z_next.tolist() != list(want_z)):
                return False
    return True


__all__ = ["CompiledLawController", "LawCall", "compiled_law_agrees", "law_library",
           "parameter_vector"]

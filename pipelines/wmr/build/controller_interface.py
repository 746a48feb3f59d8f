"""The controller FMU's interface: one Python description of its variables.

The paper's stabiliser with its wheel servos (:mod:`wmr.core.control`) is also built as a
sampled-data co-simulation FMU (``wmr_controller-fmi2.fmu``, ``wmr_controller-fmi3.fmu``) from
the hand-written C core ``fmu/src/controller/controller.c`` on the robot's FMI layer.  This
module is the one source of that FMU's variables: :func:`controller_model` describes them
(names, units, start values, bounds), and :func:`write_controller_core` writes from it the C
variable table and index macros, while :mod:`wmr.build.modeldesc` writes both model
descriptions from the same object, so that value references cannot drift apart.

Names
-----
* parameters: the scenario files' names (``goal.x_m``, ``gains.K_ps``, ``limits.v_max_mps``,
  ``params.r``, ``control_period_s``, ``stop_radius_m``, ``heading_tolerance_deg``), with the
  scenario defaults (:class:`~wmr.core.control.Gains`, :class:`~wmr.core.control.Limits`,
  :class:`~wmr.core.plant.RobotParams`, :mod:`wmr.config.scenario`);
* inputs: the robot FMU's output names (``x``, ``y``, ``theta``, ``v``, ``omega``,
  ``omega_r``, ``omega_l``);
* outputs: ``tau_r`` and ``tau_l`` (the robot FMU's input names) and every other signal of
  :data:`wmr.core.signals.CONTROL_SIGNALS` under its name without the unit suffix (``e_s``,
  ``omega_r_ref``, ``D_x``, ...), in that order, then ``phase`` (0 approach, 1 alignment) and
  ``converged`` (1 when the run would stop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Final

from wmr.build.codegen import sizes_header, variables_source, write_files
from wmr.build.flatten import ModelInterface, Variable
from wmr.core.control.stabiliser import Gains, Limits
from wmr.core.plant import RobotParams
from wmr.core.signals import CONTROL_SIGNALS
from wmr.infra.errors import BuildError

CONTROLLER_IDENTIFIER: Final = "wmr_controller"

#: The FMU's output name of each :data:`~wmr.core.signals.CONTROL_SIGNALS` column, in order.
SIGNAL_OUTPUTS: Final = (
    "dr", "e_s", "e_theta", "alpha", "beta", "gamma", "u_s", "u_theta", "p_s", "i_s",
    "p_theta", "i_theta", "omega_r_ref", "omega_l_ref", "tau_r", "tau_l", "D_x", "D_y",
    "R_x", "R_y",
)
#: Inputs, in the order of the input vector: the measured pose, speeds and wheel speeds.
INPUTS: Final = ("x", "y", "theta", "v", "omega", "omega_r", "omega_l")
#: Discrete states (``x[]`` of the FMI layer), zero at the start.
STATES: Final = ("phase", "i_s", "i_theta", "prev_gamma", "prev_beta", "servo_r_integral",
                 "servo_l_integral")

_SIGNAL_TEXT: Final = {  # (unit, description) of each output
    "dr": ("m", "distance to the goal, Delta r (eq. 26)"),
    "e_s": ("m", "distance error e_s (ROC; eqs. 25/26)"),
    "e_theta": ("rad", "angular error e_theta (gamma under ROC)"),
    "alpha": ("rad", "direction to the goal (eq. 27)"),
    "beta": ("rad", "theta_d - alpha, before the clamp (ROC)"),
    "gamma": ("rad", "2 alpha - theta_d - theta, wrapped (ROC)"),
    "u_s": ("m/s", "PI output of the distance loop (eq. 29)"),
    "u_theta": ("rad/s", "PI output of the angle loop (eq. 29)"),
    "p_s": ("m/s", "proportional term of u_s"),
    "i_s": ("m/s", "integral term of u_s"),
    "p_theta": ("rad/s", "proportional term of u_theta"),
    "i_theta": ("rad/s", "integral term of u_theta"),
    "omega_r_ref": ("rad/s", "right wheel speed reference (eq. 28)"),
    "omega_l_ref": ("rad/s", "left wheel speed reference (eq. 28)"),
    "tau_r": ("N.m", "right motor torque (wheel servo)"),
    "tau_l": ("N.m", "left motor torque (wheel servo)"),
    "D_x": ("m", "point D on the heading line, x (Fig. 4)"),
    "D_y": ("m", "point D on the heading line, y"),
    "R_x": ("m", "reference point R of the orientation control, x (Fig. 6)"),
    "R_y": ("m", "reference point R, y"),
    "phase": ("", "0 approach (RPC/ROC), 1 final alignment inside the stop radius"),
    "converged": ("", "1 when at the goal, aligned and at rest: the master ends the run"),
}
_INPUT_TEXT: Final = {
    "x": ("m", "measured x of B"), "y": ("m", "measured y of B"),
    "theta": ("rad", "measured heading"), "v": ("m/s", "measured forward speed"),
    "omega": ("rad/s", "measured turn rate"), "omega_r": ("rad/s", "measured right wheel speed"),
    "omega_l": ("rad/s", "measured left wheel speed"),
}
_GAIN_TEXT: Final = {  # (unit, description)
    "K_ps": ("1/s", "distance loop, proportional (eq. 29)"),
    "K_is": ("1/s2", "distance loop, integral (eq. 29)"),
    "K_ptheta": ("1/s", "angle loop, proportional (eq. 29)"),
    "K_itheta": ("1/s2", "angle loop, integral (eq. 29)"),
    "K_pw": ("N.m.s/rad", "wheel speed servo, proportional"),
    "K_iw": ("N.m/rad", "wheel speed servo, integral"),
}
_LIMIT_TEXT: Final = {
    "v_max_mps": ("m/s", "limit of u_s (forward only: 0 <= u_s <= v_max)"),
    "omega_max_radps": ("rad/s", "limit of the magnitude of u_theta"),
    "wheel_speed_max_radps": ("rad/s", "limit of the wheel speed references (curvature kept)"),
    "torque_max_nm": ("N.m", "motor torque saturation (servo back-calculation)"),
}
#: Robot parameters the controller knows: eq. 28 and the servos' friction feed-forward.
ROBOT_PARAMETERS: Final = {"r": ("m", 1e-3, "wheel radius (eq. 28)"),
                           "L": ("m", 1e-3, "half the track (eq. 28)"),
                           "b_f": ("N.m.s/rad", 0.0, "viscous friction, feed-forward"),
                           "tau_c": ("N.m", 0.0, "Coulomb friction, feed-forward"),
                           "w_c": ("rad/s", 1e-6, "tanh smoothing speed of tau_c")}


@dataclass
class ControllerModel(ModelInterface):
    """The variables of the controller FMU, in the shape :mod:`wmr.build.modeldesc` reads.

    Like :class:`wmr.build.flatten.FlatModel` without the CasADi functions: the law is the
    hand-written C core.  ``state_names`` are the discrete states.
    """

    start_time: float = 0.0
    stop_time: float = 120.0
    step_size: float = 0.01
    model_identifier: str = CONTROLLER_IDENTIFIER
    generated_by: str = "hand-written C"
    period_parameter: str = "control_period_s"
    source_digest: str = field(default="")


def controller_model() -> ControllerModel:
    """The controller FMU's variables with the scenario defaults."""
    from wmr.core.runspec import (
        DEFAULT_HEADING_TOLERANCE_DEG,
        DEFAULT_MAX_TIME_S,
        DEFAULT_PERIOD_S,
        DEFAULT_STOP_RADIUS_M,
    )

    params: list[tuple[str, str, str, float, float]] = [  # name, unit, text, start, min
        ("goal.x_m", "m", "goal x_d", 20.0, -math.inf),
        ("goal.y_m", "m", "goal y_d", 10.0, -math.inf),
        ("goal.heading_deg", "deg", "desired heading theta_d", 0.0, -math.inf),
    ]
    gains, limits, robot = Gains(), Limits(), RobotParams()
    for f in fields(gains):
        params.append((f"gains.{f.name}", *_GAIN_TEXT[f.name], getattr(gains, f.name), 0.0))
    for f in fields(limits):
        params.append((f"limits.{f.name}", *_LIMIT_TEXT[f.name], getattr(limits, f.name), 0.0))
    for name, (unit, lo, text) in ROBOT_PARAMETERS.items():
        params.append((f"params.{name}", unit, text, getattr(robot, name), lo))
    params += [
        ("control_period_s", "s", "control period h: samples on the grid t0 + n h",
         DEFAULT_PERIOD_S, 1e-6),
        ("stop_radius_m", "m", "stop radius epsilon (Section 4)", DEFAULT_STOP_RADIUS_M, 0.0),
        ("heading_tolerance_deg", "deg", "heading tolerance of the convergence test",
         DEFAULT_HEADING_TOLERANCE_DEG, 0.0),
    ]
    parameters = [Variable(n, "parameter", i, unit, text, start, lo)
                  for i, (n, unit, text, start, lo) in enumerate(params)]
    inputs = [Variable(n, "input", i, _INPUT_TEXT[n][0], _INPUT_TEXT[n][1], 0.0)
              for i, n in enumerate(INPUTS)]
    outputs = [Variable(n, "output", i, _SIGNAL_TEXT[n][0], _SIGNAL_TEXT[n][1], math.nan)
               for i, n in enumerate((*SIGNAL_OUTPUTS, "phase", "converged"))]
    assert len(SIGNAL_OUTPUTS) == len(CONTROL_SIGNALS)
    return ControllerModel(
        name="WMR.Controller",
        description="The paper's PI point stabiliser (RPC/ROC, eqs. 25-29) with wheel speed "
                    "servos, sampled at control_period_s (Bunjaku, Stefanovski, Stankovski)",
        parameters=parameters, inputs=inputs, outputs=outputs, state_names=list(STATES),
        stop_time=DEFAULT_MAX_TIME_S, step_size=DEFAULT_PERIOD_S)


def _c_name(name: str) -> str:
    return name.replace(".", "_")


def indices_header(model: ControllerModel) -> str:
    """``model_indices.h``: ``P_``, ``U_``, ``Y_`` and ``Z_`` index macros by name."""
    lines = [f"/* Generated by wmr fmu build from {model.name}: do not edit. */",
             "#ifndef WMR_MODEL_INDICES_H", "#define WMR_MODEL_INDICES_H"]
    for prefix, names in (("P", [v.name for v in model.parameters]),
                          ("U", [v.name for v in model.inputs]),
                          ("Y", [v.name for v in model.outputs]), ("Z", model.state_names)):
        lines += [f"#define {prefix}_{_c_name(n)} {i}" for i, n in enumerate(names)]
    lines.append("#endif")
    return "\n".join(lines) + "\n"


def controller_sources() -> list[Path]:
    """The hand-written C of the controller core."""
    from wmr.infra import paths

    sources = sorted((paths.fmu_src_dir() / "controller").glob("*.c"))
    if not sources:
        raise BuildError(f"{paths.fmu_src_dir() / 'controller'} has no C sources of the "
                         "controller; restore fmu/src/controller/controller.c")
    return sources


def write_controller_core(model: ControllerModel, token: str, out_dir: Path) -> list[Path]:
    """Write the generated files (sizes, indices, variable table) into ``out_dir``."""
    return write_files(out_dir, {
        "model_sizes.h": sizes_header(model),
        "model_indices.h": indices_header(model),
        "model_variables.c": variables_source(model, token),
    })


def index_html(model: ControllerModel) -> str:
    """``documentation/index.html`` of the controller FMUs."""
    from html import escape

    from wmr.build.documentation import PAPER, _table, html_page
    from wmr.infra.version import __version__

    return html_page(model.name, model.description, f"""\
<p>{escape(model.description)}. The point stabiliser of the paper below (reference point and
reference orientation control, eqs. 25 to 27; two PI controllers with conditional-integration
anti-windup, eq. 29; the inverse kinematics eq. 28 read as rates) with a PI speed servo per
wheel (back-calculation anti-windup, friction feed-forward), and the extensions of wmr-cosim:
final alignment inside the stop radius, forward motion only, |beta| clamped to 60 degrees,
hysteresis of the angles near +-pi. Hand-written C, built by wmr-cosim {escape(__version__)}
on the FMI layer of the robot FMU; equal to the Python controller of wmr-cosim to rounding.</p>
<p><b>Sampling.</b> The FMU samples on the grid t0 + n h, h = the parameter
<code>control_period_s</code>, whatever the communication step: <code>fmiDoStep</code> takes
every grid point of the step with the inputs set at its start, and the outputs are the sample
computed from the inputs set at a grid point (direct feedthrough), the last sample held between
grid points. Step at <code>control_period_s</code> to run the law as tuned. Connect the
robot's outputs <code>x, y, theta, v, omega, omega_r, omega_l</code> to the inputs of the same
names and <code>tau_r, tau_l</code> back to the robot. <code>converged</code> turns 1 when the
robot is at the goal, aligned and at rest. Non-finite inputs are refused with an error.</p>

<h2>Variables</h2>
{_table("Inputs", model.inputs, "start")}
{_table("Outputs", model.outputs, "start")}
{_table("Parameters", model.parameters, "default")}

<h2>Paper</h2>
<p>{escape(PAPER)}</p>
""")


__all__ = [
    "CONTROLLER_IDENTIFIER",
    "INPUTS",
    "SIGNAL_OUTPUTS",
    "STATES",
    "ControllerModel",
    "controller_model",
    "controller_sources",
    "index_html",
    "indices_header",
    "write_controller_core",
]

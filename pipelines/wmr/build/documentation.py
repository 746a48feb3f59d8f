"""The FMUs' ``documentation/`` folder: ``index.html`` (the entry point the FMI standard names)
and ``licenses/``.

The variable tables are generated from the :class:`~wmr.build.flatten.FlatModel`, so they always
list what the model description declares; the equations and the errata are the ones
``docs/model.md`` explains (a test keeps the two errata tables equal).
"""

from __future__ import annotations

import math
from html import escape

from wmr.build.flatten import FlatModel, Variable
from wmr.infra import paths
from wmr.infra.errors import BuildError
from wmr.infra.version import __version__

PAPER = ("D. Bunjaku, J. Stefanovski, M. Stankovski: Dynamic modelling and asymptotic point "
         "stabilization control of two differential wheeled mobile robot.")
LICENSE_ID = "BSD-2-Clause"

#: The model's equations as the FMU computes them, each with the paper's equation number.
EQUATIONS: tuple[tuple[str, str], ...] = (
    ("3", "omega_r = (v + L omega) / r,  omega_l = (v - L omega) / r  (rolling without slip)"),
    ("4", "x_G = x + l cos(theta),  y_G = y + l sin(theta)"),
    ("7 (corrected)", "der(x) = v cos(theta),  der(y) = v sin(theta),  der(theta) = omega"),
    ("16, 18 (corrected)", "F_d = m (der(v) - l omega^2),  "
                           "tau_d = (I_g + m l^2) der(omega) + m l v omega"),
    ("19 (corrected)", "F_d = (tau_dr + tau_dl) / r,  tau_d = L (tau_dr - tau_dl) / r"),
    ("22", "I_wm alpha + tau_d = tau_m - tau_f,  tau_f = b_f omega_w + tau_c tanh(omega_w / w_c)"
           ",  alpha = (der(v) +- L der(omega)) / r"),
    ("23, 24 (corrected)", "diag(m + 2 I_wm / r^2, I_g + m l^2 + 2 L^2 I_wm / r^2) "
                           "[der(v), der(omega)] = [m l omega^2 + (tau_r + tau_l - tau_fr - "
                           "tau_fl) / r, -m l v omega + L (tau_r - tau_l - tau_fr + tau_fl) / r]"),
    ("-", "der(phi_r) = omega_r,  der(phi_l) = omega_l;  E_kin = 1/2 (m (v^2 + (l omega)^2) + "
          "I_g omega^2 + I_wm (omega_r^2 + omega_l^2))"),
)

#: The paper's errata (the table of docs/model.md, kept equal by a test): equation, printed, used.
ERRATA: tuple[tuple[str, str, str], ...] = (
    ("6, 7", "v_G = xdot_B + ydot_G", "v_B = v e^{j theta}"),
    ("8, 16", "(v - l thetadot^2), l theta", "(vdot - l thetadot^2), l thetadot"),
    ("11, 13", "+l sin, mixed entries", "product of eq. 11 and eq. 3"),
    ("19", "L (tau_mr - tau_mr) / r (always 0)", "L (tau_r - tau_l) / r"),
    ("24", "2 I_wm / r^2 in row 1, column 2",
     "diag(m + 2 I_wm/r^2, I_g + m l^2 + 2 L^2 I_wm / r^2)"),
)


def _start(value: float) -> str:
    """A start value as a reader wants it: the shortest text that reads back as the same
    float (``repr``: 0.15, not 0.14999999999999999), "none" for a variable without one
    (an output's NaN)."""
    return "none" if math.isnan(value) else repr(value)


def _rows(variables: list[Variable]) -> str:
    return "\n".join(
        f"<tr><td><code>{escape(v.name)}</code></td><td>{escape(v.unit or '1')}</td>"
        f"<td>{_start(v.start)}</td><td>{escape(v.description)}</td></tr>" for v in variables)


def _table(title: str, variables: list[Variable], start: str) -> str:
    return (f"<h3>{escape(title)}</h3>\n<table>\n<tr><th>name</th><th>unit</th>"
            f"<th>{start}</th><th>meaning</th></tr>\n{_rows(variables)}\n</table>")


def html_page(name: str, description: str, body: str) -> str:
    """A standalone HTML page: title ``name: description``, heading ``name``, then ``body``.

    The one skeleton (and style) of every FMU's ``documentation/index.html``; ``body`` is HTML
    (escaped by the caller), ``name`` and ``description`` are plain text.
    """
    return f"""<!DOCTYPE html>
<html lang="en">
<head><meta charset="utf-8"><title>{escape(name)}: {escape(description)}</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:left}}
</style></head>
<body>
<h1>{escape(name)}</h1>
{body}</body>
</html>
"""


def index_html(model: FlatModel) -> str:
    """``documentation/index.html`` for the FMUs of ``model``."""
    equations = "\n".join(f"<tr><td>{escape(n)}</td><td><code>{escape(e)}</code></td></tr>"
                          for n, e in EQUATIONS)
    errata = "\n".join(f"<tr><td>{escape(n)}</td><td><code>{escape(p)}</code></td>"
                       f"<td><code>{escape(u)}</code></td></tr>" for n, p, u in ERRATA)
    states = ", ".join(f"<code>{escape(s)}</code> (output <code>{escape(v.name)}</code>, "
                       f"derivative <code>{escape(d.name)}</code>)"
                       for s, v, d in zip(model.state_names,
                                          sorted((v for v in model.outputs if v.state >= 0),
                                                 key=lambda v: v.state),
                                          model.derivatives, strict=True))
    return html_page(model.name, model.description, f"""\
<p>{escape(model.description)}. The two-wheeled differential-drive mobile robot of the paper
below: a rigid platform on two driving wheels that roll without slipping, each driven by a
motor with its own inertia and friction. Inputs are the two motor torques; outputs are the
pose of B (the centre of the wheel axle), the velocities, the wheel speeds and angles, the
centre of gravity G and the kinetic energy <code>E_kin</code>, which is conserved with zero
torque and no friction (a check any importer can make). Built by wmr-cosim {escape(__version__)}
from the Modelica package <code>WMR</code> (model <code>{escape(model.name)}</code>): pymoca
flattens it, the build solves it for an explicit ODE, CasADi generates the C of the model core,
and an adaptive Dormand-Prince 5(4) solver (relative tolerance 1e-9 unless the importer sets
one) integrates it inside each co-simulation step. For Model Exchange the importer's solver
integrates the states below through their derivatives <code>der(...)</code> instead. Directional
derivatives (and, in FMI 3, adjoint derivatives) come from CasADi's exact Jacobian, and the
model structure's dependencies are its sparsity: no output depends directly on the torques.
The C sources are in
<code>sources/</code>; <code>README.md</code> here describes the FMI layer.</p>

<h2>Equations</h2>
<p>Numbers are the paper's; "corrected" marks the forms the errata below replace.</p>
<table>
<tr><th>eq.</th><th>as computed</th></tr>
{equations}
</table>
<p>States: {states}.</p>

<h2>Variables</h2>
{_table("Inputs", model.inputs, "start")}
{_table("Outputs", model.outputs, "start")}
{_table("Parameters", model.parameters, "default")}

<h2>Paper</h2>
<p>{escape(PAPER)} The default parameters are the paper's Section 5 values.</p>

<h2>Errata of the paper</h2>
<table>
<tr><th>eq.</th><th>printed</th><th>used</th></tr>
{errata}
</table>
<p>Coulomb friction is smoothed with <code>tanh</code> over the speed <code>w_c</code>: a sign
function has no solution at rest for an explicit ODE. The wheels' mass is in neither the paper's
model nor this one.</p>

<h2>Licence</h2>
<p>{LICENSE_ID}, see <code>licenses/LICENSE.txt</code>.</p>
""")


def license_files() -> dict[str, bytes]:
    """``documentation/licenses/`` members: the project's licence."""
    path = paths.license_file()
    if not path.is_file():
        raise BuildError(f"the licence file {path} is missing; restore LICENSE from git")
    return {"documentation/licenses/LICENSE.txt": path.read_bytes()}

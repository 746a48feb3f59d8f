"""Flatten the Modelica model with pymoca and solve it for an explicit ODE.

pymoca gives the flattened model as implicit CasADi equations ``g(z, x, u, p) = 0`` in the
unknowns ``z`` (state derivatives and algebraic variables).  For this robot every equation is
affine in ``z`` (the mass matrix depends on the state only through the parameters), so the
system is put into block-triangular form and each block is solved symbolically; an equation
that is nonlinear in the unknowns stops the build with the names involved, rather than being
left to a Newton iteration inside the FMU.

The result, :class:`FlatModel`, is the one source of the value references, start values, units
and descriptions of both model descriptions and of the generated C variable table.
"""

from __future__ import annotations

import hashlib
import math
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import casadi as ca
import numpy as np

from wmr.infra.errors import BuildError

Kind = Literal["parameter", "input", "output", "derivative"]


#: The robot FMU's model identifier (its binaries' and archives' name), in both model
#: descriptions and the C core.
MODEL_IDENTIFIER = "wmr_robot"


@dataclass(frozen=True)
class Variable:
    """One variable of the FMU interface.

    ``index`` is the position in the parameter, input, output or state-derivative vector of
    the generated code; the value reference is assigned by :attr:`FlatModel.variables` order
    (time is 0).  ``state`` is the position in the state vector of an output that is a
    continuous state (-1 otherwise); ``display_unit`` is Modelica's ``displayUnit``.
    """

    name: str
    kind: Kind
    index: int
    unit: str
    description: str
    start: float
    min: float = -math.inf
    max: float = math.inf
    tunable: bool = False
    state: int = -1
    display_unit: str = ""


@dataclass
class ModelInterface:
    """What an FMU's model description declares of a model: its name, variables and states.

    :class:`FlatModel` (the robot) and :class:`wmr.build.controller_interface.ControllerModel`
    extend it; each keeps its own default experiment (start, stop, step), whose defaults differ.
    """

    name: str
    description: str
    parameters: list[Variable]
    inputs: list[Variable]
    outputs: list[Variable]
    state_names: list[str]

    @property
    def variables(self) -> list[Variable]:
        """Parameters, inputs then outputs: value reference = position + 1 (0 is time)."""
        return [*self.parameters, *self.inputs, *self.outputs]

    @property
    def value_references(self) -> dict[str, int]:
        return {v.name: i + 1 for i, v in enumerate(self.variables)}


@dataclass
class FlatModel(ModelInterface):
    """The explicit form ``xdot = f(x, u, p)``, ``y = h(x, u, p)``, ``x(0) = x0(p)``.

    Every continuous state is also an output (``Variable.state``); ``derivatives`` holds one
    ``der(<output>)`` variable per state, in state order (the FMI state vector order).
    """

    ode: ca.Function  # (x, u, p) -> xdot
    out: ca.Function  # (x, u, p) -> y
    init: ca.Function  # (p) -> x0
    start_time: float = 0.0
    stop_time: float = 60.0
    step_size: float = 0.01
    #: The relative tolerance the FMU's own solver uses by default (SOLVER_DEFAULT_RTOL).
    tolerance: float = 1e-9
    source_digest: str = field(default="")
    derivatives: list[Variable] = field(default_factory=list)

    @property
    def variables(self) -> list[Variable]:
        """Parameters, inputs, outputs then state derivatives: value reference = position + 1
        (0 is time), so that the references of the first three never move."""
        return [*self.parameters, *self.inputs, *self.outputs, *self.derivatives]


def _modelica_files(modelica_dir: Path) -> list[Path]:
    return sorted(p for p in modelica_dir.rglob("*") if p.suffix in {".mo", ".order"})


def source_digest(modelica_dir: Path) -> str:
    """SHA-256 over the Modelica sources (names and bytes)."""
    h = hashlib.sha256()
    for path in _modelica_files(modelica_dir):
        h.update(path.relative_to(modelica_dir).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


_PARSER_LOCK = threading.Lock()


@contextmanager
def _uncached_parser() -> Iterator[None]:
    """pymoca's parser with its cache off meanwhile.

    ``pymoca.parser.parse_text`` keeps parsed files as pickles in
    ``$XDG_CACHE_HOME/pymoca/model_txt_cache.db`` (one database for every user who shares that
    folder) and unpickles a hit: a planted row runs code as whoever builds.  pymoca's own
    callers on the build path (``transfer_model``, lazy classes) take no option for it, so the
    module's function is wrapped, with ``bypass_cache`` forced, for the duration; our few
    files parse in about 0.2 s without it.
    """
    import pymoca.parser as parser

    with _PARSER_LOCK:
        original = parser.parse_text

        def parse_text(txt: str, /, *args: Any, **kwargs: Any) -> Any:
            kwargs["bypass_cache"] = True
            return original(txt, *args, **kwargs)

        parser.parse_text = parse_text
        try:
            yield
        finally:
            parser.parse_text = original


def _tree_symbols(modelica_dir: Path,
                  model_name: str) -> tuple[dict[str, object], str, dict[str, float]]:
    """Comments, units and the experiment annotation from pymoca's flattened tree."""
    import pymoca.ast as ast
    import pymoca.parser as parser
    import pymoca.tree as tree

    root = None
    for path in _modelica_files(modelica_dir):
        if path.suffix != ".mo":
            continue
        try:
            parsed = parser.parse(path.read_text())
        except Exception as exc:  # pymoca raises bare Exceptions on syntax errors
            raise BuildError(f"{path}: Modelica syntax error: {exc}") from exc
        if parsed is None:
            raise BuildError(f"{path}: Modelica syntax error (pymoca could not parse it)")
        if root is None:
            root = parsed
        else:
            root.extend(parsed)
    if root is None:
        raise BuildError(f"no Modelica files in {modelica_dir}")
    try:
        flat = tree.flatten(root, ast.ComponentRef.from_string(model_name))
    except Exception as exc:
        raise BuildError(f"pymoca cannot flatten {model_name}: {exc}") from exc
    cls = next(iter(flat.classes.values()))
    experiment: dict[str, float] = {}
    ann = getattr(cls, "annotation", None)
    modifications = getattr(ann, "modification_environment", None)
    if modifications is not None:  # pragma: no cover - depends on pymoca internals
        pass
    description = ""
    root_cls = root.classes.get(model_name.split(".")[0])
    if root_cls is not None:
        sub = root_cls.classes.get(model_name.split(".")[-1])
        if sub is not None:
            description = str(getattr(sub, "comment", "") or "")
    return dict(cls.symbols), description, experiment


def _value(symbol: object, attr: str) -> object:
    prim = getattr(symbol, attr, None)
    return getattr(prim, "value", prim)


def _float(value: object, default: float) -> float:
    if value is None:
        return default
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return default


def flatten(modelica_dir: Path, model_name: str = "WMR.Robot") -> FlatModel:
    """Translate ``model_name`` from ``modelica_dir`` into an explicit :class:`FlatModel`.

    Raises
    ------
    BuildError
        When pymoca cannot translate the model, a parameter has no value, or the equations
        are not an affine system in the derivatives and algebraic variables.
    """
    from pymoca.backends.casadi.api import transfer_model

    with _uncached_parser():
        symbols, description, _ = _tree_symbols(modelica_dir, model_name)
        try:
            # "cache": False keeps pymoca's other pickle (MODEL.pymoca_cache beside the
            # sources) out too
            model = transfer_model(str(modelica_dir), model_name, {"cache": False})
        except Exception as exc:
            raise BuildError(f"pymoca cannot translate {model_name}: {exc}") from exc

    # Parameters bound to other parameters (platform.m = m) are substituted away; the free
    # ones (a literal value) are the FMU's parameters.
    free: list[ca.MX] = []
    free_values: list[float] = []
    bound_sym: list[ca.MX] = []
    bound_expr: list[ca.MX] = []
    for par in model.parameters:
        value = par.value
        if isinstance(value, ca.MX) and not value.is_constant():
            bound_sym.append(par.symbol)
            bound_expr.append(value)
        else:
            free.append(par.symbol)
            free_values.append(float(value))

    def substitute(exprs: list[ca.MX]) -> list[ca.MX]:
        for _ in range(len(bound_sym) + 1):
            if not any(ca.depends_on(e, b) for e in exprs for b in bound_sym):
                return exprs
            exprs = ca.substitute(exprs, bound_sym, bound_expr)
        raise BuildError("parameter bindings are circular: " + ", ".join(map(str, bound_sym)))

    x = [s.symbol for s in model.states]
    xdot = [s.symbol for s in model.der_states]
    alg = [s.symbol for s in model.alg_states]
    u = [s.symbol for s in model.inputs]
    z = xdot + alg
    if len(model.equations) != len(z):
        raise BuildError(
            f"{model_name}: {len(model.equations)} equations for {len(z)} unknowns "
            f"({', '.join(map(str, z))})"
        )
    eqs = substitute(list(model.equations))
    starts = substitute([ca.MX(s.start) if not isinstance(s.start, ca.MX) else s.start
                         for s in model.states])

    X, U, P, Z = ca.vcat(x), ca.vcat(u), ca.vcat(free), ca.vcat(z)
    g = ca.Function("g", [Z, X, U, P], [ca.vcat(eqs)]).expand()
    zs = ca.SX.sym("z", Z.numel())
    xs = ca.SX.sym("x", X.numel())
    us = ca.SX.sym("u", U.numel())
    ps = ca.SX.sym("p", P.numel())
    gs = g(zs, xs, us, ps)
    sol = _solve_blocks(gs, zs, [str(v) for v in z])

    # Self-check: the solution satisfies the implicit equations at random points.
    check = ca.Function("check", [xs, us, ps], [ca.substitute(gs, zs, sol)])
    rng = np.random.default_rng(0)
    for _ in range(5):
        pv = np.array(free_values) * (1 + 0.1 * rng.standard_normal(len(free_values))) + 0.01
        res = np.asarray(check(rng.standard_normal(len(x)), rng.standard_normal(len(u)), pv))
        if not np.all(np.abs(res) < 1e-8 * (1 + np.max(np.abs(pv)))):
            raise BuildError(f"the explicit solution does not satisfy the equations: {res.ravel()}")

    zmap = {str(s): i for i, s in enumerate(z)}
    xdot_expr = ca.vcat([sol[zmap[str(d)]] for d in xdot])
    state_index = {str(s): i for i, s in enumerate(x)}
    out_exprs = []
    for name in model.outputs:
        if name in zmap:
            out_exprs.append(sol[zmap[name]])
        elif name in state_index:
            out_exprs.append(xs[state_index[name]])
        else:
            raise BuildError(f"output {name} is neither a state nor an algebraic variable")
    ode = ca.Function("wmr_ode", [xs, us, ps], [xdot_expr], ["x", "u", "p"], ["xdot"])
    out = ca.Function("wmr_out", [xs, us, ps], [ca.vcat(out_exprs)], ["x", "u", "p"], ["y"])
    init_mx = ca.Function("init", [P], [ca.vcat(starts)])
    init = ca.Function("wmr_init", [ps], [init_mx(ps)], ["p"], ["x0"]).expand()

    # Parameters that set a start value only act at initialisation: not tunable.
    start_deps = ca.vcat(starts)
    def describe(name: str) -> tuple[str, str, float, float, str]:
        sym = symbols.get(name)
        unit = str(_value(sym, "unit") or "") if sym is not None else ""
        comment = str(getattr(sym, "comment", "") or "") if sym is not None else ""
        lo = _float(_value(sym, "min"), -math.inf) if sym is not None else -math.inf
        hi = _float(_value(sym, "max"), math.inf) if sym is not None else math.inf
        display = str(_value(sym, "displayUnit") or "") if sym is not None else ""
        return unit, comment, lo, hi, display

    parameters = []
    for i, (sym, val) in enumerate(zip(free, free_values, strict=True)):
        unit, comment, lo, hi, display = describe(str(sym))
        parameters.append(Variable(str(sym), "parameter", i, unit, comment, val, lo, hi,
                                   tunable=not ca.depends_on(start_deps, sym),
                                   display_unit=display))
    inputs = []
    for i, var in enumerate(model.inputs):
        unit, comment, lo, hi, display = describe(str(var.symbol))
        start = _float(var.start if not isinstance(var.start, ca.MX) else None, 0.0)
        inputs.append(Variable(str(var.symbol), "input", i, unit, comment, start, lo, hi,
                               display_unit=display))
    outputs = []
    for i, name in enumerate(model.outputs):
        unit, comment, lo, hi, display = describe(name)
        outputs.append(Variable(name, "output", i, unit, comment, math.nan, lo, hi,
                                display_unit=display))

    # Declaration order of the Modelica source (pymoca's flattened tree keeps it) fixes the
    # value references, so that they only move when the model's interface moves.
    order = {name: i for i, name in enumerate(symbols)}
    parameters.sort(key=lambda v: order.get(v.name, len(order)))
    outputs.sort(key=lambda v: order.get(v.name, len(order)))
    out = ca.Function("wmr_out", [xs, us, ps],
                      [ca.vcat([out_exprs[v.index] for v in outputs])], ["x", "u", "p"], ["y"])
    perm = [v.index for v in parameters]
    p_new = ca.SX.sym("p", len(perm))
    p_old = ca.vcat([p_new[perm.index(i)] for i in range(len(perm))])
    ode = ca.Function("wmr_ode", [xs, us, p_new], [ode(xs, us, p_old)], ["x", "u", "p"], ["xdot"])
    out = ca.Function("wmr_out", [xs, us, p_new], [out(xs, us, p_old)], ["x", "u", "p"], ["y"])
    init = ca.Function("wmr_init", [p_new], [init(p_old)], ["p"], ["x0"])
    parameters = [replace(v, index=i) for i, v in enumerate(parameters)]
    outputs = [replace(v, index=i) for i, v in enumerate(outputs)]
    outputs, derivatives = _states_as_outputs(outputs, out, [str(s) for s in x])

    return FlatModel(
        name=model_name,
        description=description,
        parameters=parameters,
        inputs=inputs,
        outputs=outputs,
        state_names=[str(s) for s in x],
        ode=ode,
        out=out,
        init=init,
        source_digest=source_digest(modelica_dir),
        derivatives=derivatives,
    )


def _per_second(unit: str) -> str:
    """The unit of the time derivative of a quantity in ``unit`` (m -> m/s, m/s -> m/s2)."""
    if not unit:
        return "1/s"
    return unit + "2" if unit.endswith("/s") else unit + "/s"


def _states_as_outputs(outputs: list[Variable], out: ca.Function,
                       state_names: list[str]) -> tuple[list[Variable], list[Variable]]:
    """Mark the output that is each continuous state, and make its ``der()`` variable.

    An output is the state ``x_i`` when CasADi's expression for it is the symbol ``x_i``
    itself (``phi_r = wheelR.phi``).  FMI needs every state to be a variable; exposing it
    through its output keeps the interface's names and value references.
    """
    xs = ca.SX.sym("x", out.numel_in(0))
    y = out(xs, ca.SX.sym("u", out.numel_in(1)), ca.SX.sym("p", out.numel_in(2)))
    outputs = list(outputs)
    derivatives = []
    for i, name in enumerate(state_names):
        match = [j for j, v in enumerate(outputs) if ca.is_equal(y[v.index], xs[i])]
        if not match:
            raise BuildError(f"the continuous state {name} is no output of the model; declare an "
                             f"output equal to it (e.g. output Real ... = {name})")
        v = outputs[match[0]] = replace(outputs[match[0]], state=i)
        derivatives.append(Variable(f"der({v.name})", "derivative", i, _per_second(v.unit),
                                    f"Time derivative of {v.name}", math.nan))
    return outputs, derivatives


def _solve_blocks(g: ca.SX, z: ca.SX, names: list[str]) -> ca.SX:
    """Solve ``g(z) = 0`` for ``z`` block by block in block-triangular form.

    Each block must be affine in its own unknowns once the blocks it depends on are solved
    (tanh(omega_r) is fine: omega_r is known by then); a block that is not stops the build.
    """
    n = z.numel()
    jac = ca.jacobian(g, z)
    sp = jac.sparsity()
    if ca.sprank(sp) < n:
        raise BuildError("the model equations are structurally singular")
    nb, rowperm, colperm, rowblock, colblock, _, _ = sp.btf()
    solution: dict[int, ca.SX] = {}
    # btf() orders the blocks so that each depends only on blocks before it.
    for b in range(nb):
        rows = [rowperm[i] for i in range(rowblock[b], rowblock[b + 1])]
        cols = [colperm[i] for i in range(colblock[b], colblock[b + 1])]
        known = sorted(solution)
        gb = g[rows]
        if known:
            gb = ca.substitute(gb, ca.vcat([z[j] for j in known]),
                               ca.vcat([solution[j] for j in known]))
        solution.update(_solve_block(gb, [z[j] for j in cols], cols, names))
    result = ca.vcat([solution[j] for j in range(n)])
    if ca.depends_on(result, z):
        raise BuildError("the block-triangular solution still depends on the unknowns")
    return result


def _solve_block(g: ca.SX, unknowns: list[ca.SX], cols: list[int],
                 names: list[str]) -> dict[int, ca.SX]:
    """Solve one block ``g(z_b) = 0``, affine in ``z_b``.

    Unknowns with a constant non-zero coefficient (assignments such as ``F_d = ...``) are
    eliminated first, exactly; only the rest (here the 2 x 2 mass-matrix system of eq. 23) goes
    to a symbolic QR solve.  A pivot that could vanish for some parameter value (``I_wm``) is
    never chosen by elimination, so the result holds for every admissible parameter.
    """
    eqs = [g[i] for i in range(g.numel())]
    zb = ca.vcat(unknowns)
    if ca.depends_on(ca.jacobian(ca.vcat(eqs), zb), zb):
        raise BuildError(
            "the model is nonlinear in " + ", ".join(names[j] for j in cols)
            + "; the build only solves blocks that are affine in their unknowns"
        )
    pending = list(range(len(unknowns)))
    eliminated: list[tuple[int, ca.SX]] = []  # (unknown, expression in the remaining unknowns)
    progress = True
    while progress and len(pending) > 1:
        progress = False
        for e_idx, eq in enumerate(eqs):
            for k in pending:
                coeff = ca.jacobian(eq, unknowns[k])
                if coeff.is_constant() and float(coeff) != 0.0:
                    expr = unknowns[k] - eq / float(coeff)  # eq = c z_k + rest = 0
                    expr = ca.substitute(expr, unknowns[k], ca.SX(0))  # -rest / c
                    eqs = [ca.substitute(e, unknowns[k], expr)
                           for i, e in enumerate(eqs) if i != e_idx]
                    eliminated = [(j, ca.substitute(x, unknowns[k], expr)) for j, x in eliminated]
                    eliminated.append((k, expr))
                    pending.remove(k)
                    progress = True
                    break
            if progress:
                break
    core = ca.vcat([unknowns[k] for k in pending])
    a = ca.jacobian(ca.vcat(eqs), core)
    rhs = -ca.substitute(ca.vcat(eqs), core, ca.SX.zeros(core.numel()))
    core_sol = rhs / a if len(pending) == 1 else ca.solve(a, rhs)
    result = {cols[k]: core_sol[i] for i, k in enumerate(pending)}
    for k, expr in eliminated:
        result[cols[k]] = ca.substitute(expr, core, core_sol)
    return result

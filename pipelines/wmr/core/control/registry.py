r"""Every controller a run can use, in one registry: the paper's PI, the peers, and plug-ins.

A controller is a :class:`ControllerInfo`: its name (``RunSpec.controller``, ``wmr run
--controller NAME``), its gains (:class:`Gain`: name, default, unit, and the bounds ``wmr tune``
searches), how to make its law from a run (a :class:`~wmr.core.runspec.RunSpec`, seen here as
a :class:`LawSpec`), and the signals the law fills, by name (of
:data:`wmr.core.signals.LAW_SIGNALS`).  Every command reads it: ``wmr run``, ``wmr batch``
(``controller`` as a dimension), ``wmr benchmark --controllers``, ``wmr tune --controller``,
the scenario files and ``wmr.run(controller=..., controller_gains=...)``.

The law is a point stabiliser (:class:`wmr.core.control.Stabiliser`: ``reset``, ``update(x, y,
theta)`` returning the declared signals in the declared order, ``converged``,
``heading_error``); :func:`make_controller` puts it on the paper's two wheel speed servos (the
Fig. 7 structure, :class:`~wmr.core.control.ServoedController`), so that every controller has
the same actuators, torque limit and C fast path (``docs/architecture.md``, "The C stepper"),
and the signals it does not fill are logged as NaN.

Built in: ``pi`` (the paper's, eq. 29; its gains are ``RunSpec.gains``, the ``[gains]``
table), ``astolfi`` and ``graceful`` (:mod:`wmr.core.control.peers`; their gains are
``RunSpec.controller_gains``).  Any other installed package adds controllers with entry points
of the group :data:`ENTRY_POINT_GROUP` (``docs/plugins.md``)::

    [project.entry-points."wmr.controllers"]
    turn-then-drive = "wmr_example_controller:CONTROLLER"

each naming a :class:`ControllerInfo` of the same name.  Plug-ins are found and imported only
when a name that is not built in is asked for; a broken one is one line naming its package and
its entry point, for the command that asked for it only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from functools import cache
from typing import TYPE_CHECKING, Any, Final, Protocol

from wmr.core.control import ServoedController
from wmr.core.control.peers import (
    AstolfiGains,
    AstolfiStabiliser,
    GracefulGains,
    GracefulStabiliser,
)
from wmr.core.control.stabiliser import Gains, Limits, PointStabiliser
from wmr.core.plant import Pose, RobotParams
from wmr.core.signals import LAW_INDEX, LAW_SIGNALS, WHEEL_REFERENCES
from wmr.infra import plugins
from wmr.infra.errors import ConfigError

if TYPE_CHECKING:
    from wmr.core.control import Stabiliser

#: The entry-point group of controller plug-ins.
ENTRY_POINT_GROUP: Final = "wmr.controllers"
#: The table of a scenario or batch spec that holds a controller's own gains.
CONTROLLER_GAINS: Final = "controller_gains"
#: The PI's gains are the run's ``[gains]`` (``RunSpec.gains``, shared with the wheel servos).
RUN_GAINS: Final = "gains"
#: Characters a controller's name may hold (it is a file name, a CSV cell and a list item).
_NAME_CHARS: Final = frozenset("abcdefghijklmnopqrstuvwxyz0123456789_-.")


class LawSpec(Protocol):
    """What a controller's law is made from: the run's fields that :class:`ControllerInfo`'s
    ``make`` and :func:`make_controller` read.  A :class:`~wmr.core.runspec.RunSpec` is one
    (the registry names this protocol, not the class: a run spec checks its controller's
    gains here when it is made, so the registry must not import it back)."""

    @property
    def name(self) -> str: ...
    @property
    def start(self) -> Pose: ...
    @property
    def goal(self) -> Pose: ...
    @property
    def params(self) -> RobotParams: ...
    @property
    def gains(self) -> Gains: ...
    @property
    def limits(self) -> Limits: ...
    @property
    def period_s(self) -> float: ...
    @property
    def stop_radius_m(self) -> float: ...
    @property
    def t_max_s(self) -> float: ...
    @property
    def heading_tolerance_rad(self) -> float: ...
    @property
    def controller(self) -> str: ...
    @property
    def controller_gains(self) -> tuple[tuple[str, float], ...]: ...


@dataclass(frozen=True)
class Gain:
    """One gain a controller declares.

    Parameters
    ----------
    name
        Its key in ``[controller_gains]`` (or ``[gains]`` for the PI).
    default
        The value a run takes when none is given.
    unit
        Its SI unit (``1/s``, ``m``, ``1`` for none).
    bounds
        ``(low, high)``: the box ``wmr tune`` searches, ``low < high``, both of the default's
        sign (the search runs in the logarithm of the magnitude); ``None``: not tuned.
    doc
        One line: what it does.
    """

    name: str
    default: float
    unit: str
    bounds: tuple[float, float] | None = None
    doc: str = ""


@dataclass(frozen=True)
class ControllerInfo:
    """A controller of the registry: what it is called, its gains, its law and its signals.

    Parameters
    ----------
    name
        ``RunSpec.controller``: lower case letters, digits, ``_``, ``-`` and ``.``.
    summary
        One line for the help and the docs.
    make
        ``make(spec, gains)``: the law of one run, a fresh
        :class:`~wmr.core.control.Stabiliser` for ``spec`` (its goal, limits, robot, period,
        stop radius) with ``gains``, every declared gain by name (the run's values over the
        defaults, already checked).
    gains
        Its gains, in the order ``wmr tune`` prints them.
    signals
        The :data:`wmr.core.signals.LAW_SIGNALS` its law's ``update`` returns, in that order;
        they must include the wheel speed references (the servos' inputs).
    check
        ``check(gains)`` raises a :class:`~wmr.infra.errors.ConfigError` (field
        ``controller_gains.<gain>``) for gains outside the law's admissible set (beyond
        finiteness, which the registry checks); ``None``: any finite values.
    tuned
        Gains measured by ``wmr tune`` (the ``NAME-tuned`` row of ``wmr benchmark``); empty:
        none.
    gains_table
        :data:`CONTROLLER_GAINS` (a controller's own table); :data:`RUN_GAINS` is the PI's.
    """

    name: str
    summary: str
    make: Callable[[LawSpec, Mapping[str, float]], Stabiliser]
    gains: tuple[Gain, ...] = ()
    signals: tuple[str, ...] = LAW_SIGNALS
    check: Callable[[Mapping[str, float]], object] | None = None
    tuned: Mapping[str, float] = field(default_factory=dict)
    gains_table: str = CONTROLLER_GAINS

    def __post_init__(self) -> None:
        """Refuse a declaration that cannot work (a plug-in's mistake, named when loaded)."""
        if not self.name or not set(self.name) <= _NAME_CHARS or self.name.endswith("-tuned"):
            raise ValueError(f"controller name {self.name!r}: use lower case letters, digits, "
                             "'_', '-' or '.' (not ending in -tuned)")
        names = [g.name for g in self.gains]
        if len(set(names)) != len(names):
            raise ValueError(f"controller {self.name}: a gain is declared twice: {names}")
        for g in self.gains:
            if isinstance(g.default, bool) or not isinstance(g.default, int | float) \
                    or not math.isfinite(g.default):
                raise ValueError(f"controller {self.name}: gain {g.name}'s default must be a "
                                 f"finite number, got {g.default!r}")
            if g.bounds is not None:
                lo, hi = g.bounds
                if not (math.isfinite(lo) and math.isfinite(hi) and lo * hi > 0.0
                        and lo < hi and lo <= g.default <= hi):
                    raise ValueError(f"controller {self.name}: gain {g.name}'s bounds {g.bounds}"
                                     " must be (low, high), finite, of one sign, around its "
                                     "default")
        unknown = [s for s in self.signals if s not in LAW_INDEX]
        if unknown or len(set(self.signals)) != len(self.signals):
            raise ValueError(f"controller {self.name}: signals {unknown or self.signals} are "
                             f"not distinct names of {', '.join(LAW_SIGNALS)}")
        missing = [s for s in WHEEL_REFERENCES if s not in self.signals]
        if missing:
            raise ValueError(f"controller {self.name}: its law must fill {', '.join(missing)} "
                             "(the wheel servos' references)")
        extra = set(self.tuned) - set(names)
        if extra:
            raise ValueError(f"controller {self.name}: tuned gains {sorted(extra)} are not "
                             "declared")
        if self.gains_table not in (CONTROLLER_GAINS, RUN_GAINS):
            raise ValueError(f"controller {self.name}: gains_table must be {CONTROLLER_GAINS!r}")

    def defaults(self) -> dict[str, float]:
        """Every declared gain at its default."""
        return {g.name: float(g.default) for g in self.gains}

    def tunable(self) -> tuple[Gain, ...]:
        """The gains ``wmr tune`` searches (those with bounds)."""
        return tuple(g for g in self.gains if g.bounds is not None)

    def checked_gains(self, values: Mapping[str, Any] | None = None) -> dict[str, float]:
        """The run's gains: ``values`` over the defaults, checked.

        For the PI (whose gains are ``[gains]``) ``values`` must be empty, and the result is.

        Raises
        ------
        ConfigError
            A gain it does not declare, a value that is not a finite number, or gains its
            ``check`` refuses.
        """
        values = dict(values or {})
        if self.gains_table == RUN_GAINS:
            if values:
                raise ConfigError(CONTROLLER_GAINS, f"the {self.name.upper()} takes its gains "
                                  f"from [{RUN_GAINS}]", f"move them to the [{RUN_GAINS}] table")
            return {}
        allowed = [g.name for g in self.gains]
        for key in values:
            if key not in allowed:
                raise ConfigError(f"{CONTROLLER_GAINS}.{key}", f"not a gain of {self.name}",
                                  f"allowed: {', '.join(allowed)}" if allowed
                                  else f"{self.name} has no gains")
        out = self.defaults()
        for key, value in values.items():
            if not isinstance(value, int | float) or not math.isfinite(value):
                raise ConfigError(f"{CONTROLLER_GAINS}.{key}", f"must be a finite number, got "
                                  f"{value!r}", "give a real number")
            out[key] = float(value)
        if self.check is not None:
            self.check(out)
        return out


def _gains_of(cls: type, units: Mapping[str, str],
              bounds: Mapping[str, tuple[float, float]]) -> tuple[Gain, ...]:
    """The gains of a frozen gains dataclass, its field defaults the defaults (one source)."""
    return tuple(Gain(f.name, float(f.default), units[f.name], bounds.get(f.name))
                 for f in fields(cls) if isinstance(f.default, int | float))


def _make_pi(spec: LawSpec, gains: Mapping[str, float]) -> Stabiliser:
    goal, p = spec.goal, spec.params
    return PointStabiliser(goal.x_m, goal.y_m, goal.heading_rad, spec.gains, spec.limits, p.r,
                           p.L, spec.period_s, spec.stop_radius_m)


def _astolfi_gains(gains: Mapping[str, float]) -> AstolfiGains:
    # ``reverse`` is a flag, given as 0 or 1 like every gain of a scenario table
    return AstolfiGains(**gains)  # type: ignore[arg-type]


def _make_astolfi(spec: LawSpec, gains: Mapping[str, float]) -> Stabiliser:
    return AstolfiStabiliser(spec.goal, _astolfi_gains(gains), spec.limits, spec.params,
                             spec.period_s, spec.stop_radius_m)


def _make_graceful(spec: LawSpec, gains: Mapping[str, float]) -> Stabiliser:
    return GracefulStabiliser(spec.goal, GracefulGains(**gains), spec.limits, spec.params,
                              spec.period_s, spec.stop_radius_m)


_PER_S: Final = "1/s"

#: The controllers of ``wmr`` itself, by name, in the order of the help and the benchmark.
#: The tuned gains are measured with ``wmr tune --controller C`` (default set, budget 60;
#: ``docs/benchmark.md``); the bounds are the box ``wmr tune`` searches: the PI's four gains of
#: eq. 29 (the servos stay as designed), Astolfi's three, and the graceful law's two curvature
#: gains and the speed-law coefficient beta.
BUILTINS: Final[Mapping[str, ControllerInfo]] = {c.name: c for c in (
    ControllerInfo(
        "pi", "the paper's point stabiliser: RPC/ROC errors, two PIs (eq. 29), D^-1 (eq. 28)",
        _make_pi,
        _gains_of(Gains, {"K_ps": _PER_S, "K_is": "1/s^2", "K_ptheta": _PER_S,
                          "K_itheta": "1/s^2", "K_pw": "N m s/rad", "K_iw": "N m/rad"},
                  {"K_ps": (0.05, 5.0), "K_is": (1e-4, 1.0), "K_ptheta": (0.2, 20.0),
                   "K_itheta": (1e-3, 10.0)}),
        tuned={"K_ps": 0.418, "K_is": 0.282, "K_ptheta": 17.0, "K_itheta": 0.297},
        gains_table=RUN_GAINS),
    ControllerInfo(
        "astolfi", "Astolfi's polar law (Siegwart & Nourbakhsh, 3.6.2.4), backward driving",
        _make_astolfi,
        _gains_of(AstolfiGains, {"k_rho": _PER_S, "k_alpha": _PER_S, "k_beta": _PER_S,
                                 "reverse": "1", "k_align_theta": _PER_S, "k_align_s": _PER_S},
                  {"k_rho": (0.1, 30.0), "k_alpha": (0.2, 60.0), "k_beta": (-30.0, -0.01)}),
        check=_astolfi_gains, tuned={"k_rho": 3.88, "k_alpha": 7.57, "k_beta": -1.65}),
    ControllerInfo(
        "graceful", "Park & Kuipers' graceful law (nav2_graceful_controller)",
        _make_graceful,
        _gains_of(GracefulGains, {"k_phi": "1", "k_delta": "1", "beta": "m^lam", "lam": "1",
                                  "slowdown_radius_m": "m", "v_min_mps": "m/s",
                                  "k_align_theta": _PER_S, "k_align_s": _PER_S},
                  {"k_phi": (0.05, 20.0), "k_delta": (0.05, 20.0), "beta": (1e-3, 5.0)}),
        check=lambda gains: GracefulGains(**gains),
        tuned={"k_phi": 0.330, "k_delta": 19.7, "beta": 0.0288}),
)}
#: Their names (the default rows of ``wmr benchmark``; reserved: a plug-in of one of these
#: names is never used).
BUILTIN_NAMES: Final = tuple(BUILTINS)


def names() -> tuple[str, ...]:
    """Every controller's name: the built-in ones, then the plug-ins' (none imported)."""
    plugged = [n for n in plugins.entry_points(ENTRY_POINT_GROUP) if n not in BUILTIN_NAMES]
    return (*BUILTIN_NAMES, *plugged)


def _unknown(name: object, field_name: str) -> ConfigError:
    shown = repr(name) if len(repr(name)) <= 60 else f"{repr(name)[:60]}..."
    return ConfigError(field_name, f"unknown controller {shown}", f"one of: {', '.join(names())}")


@cache
def _plugin(name: str) -> ControllerInfo:
    found = plugins.entry_points(ENTRY_POINT_GROUP).get(name, ())
    if not found:
        raise KeyError(name)
    if len(found) > 1:
        raise plugins.PluginError(f"controller {name!r} is declared twice: "
                                  + " and ".join(plugins.describe(ep) for ep in found))
    ep = found[0]
    info = plugins.load(ep)
    if not isinstance(info, ControllerInfo):
        raise plugins.PluginError(f"{plugins.describe(ep)} is a {type(info).__name__}, not a "
                                  "wmr.core.control.registry.ControllerInfo")
    if info.name != name:
        raise plugins.PluginError(f"{plugins.describe(ep)} declares a controller named "
                                  f"{info.name!r}: the entry point's name must be the same")
    return info


def get(name: object, field_name: str = "controller") -> ControllerInfo:
    """The controller ``name`` (a plug-in is imported on its first use).

    Raises
    ------
    ConfigError
        ``field_name``: an unknown name (listing the known ones), or a plug-in that does not
        load (naming its package and entry point).
    """
    if not isinstance(name, str):
        raise _unknown(name, field_name)
    info = BUILTINS.get(name)
    if info is not None:
        return info
    try:
        return _plugin(name)
    except KeyError:
        raise _unknown(name, field_name) from None
    except plugins.PluginError as exc:
        raise ConfigError(field_name, str(exc), "fix or uninstall that package") from None


def check_gains(name: str, values: Mapping[str, Any] | None = None) -> dict[str, float]:
    """The run's own gains of controller ``name``: ``values`` over its defaults, checked
    (empty for the PI, whose gains are ``RunSpec.gains``).

    Raises
    ------
    ConfigError
        Unknown controller, unknown gain name, or gains out of range.
    """
    return get(name).checked_gains(values)


class _Scattered:
    """A law that fills some of :data:`~wmr.core.signals.LAW_SIGNALS`, seen as one that fills
    them all: the columns it does not fill are NaN."""

    __slots__ = ("at", "converged", "heading_error", "law", "reset")

    def __init__(self, law: Stabiliser, signals: tuple[str, ...]) -> None:
        self.law = law
        self.at = tuple(LAW_INDEX[s] for s in signals)
        self.reset = law.reset
        self.converged = law.converged
        self.heading_error = law.heading_error

    def update(self, x: float, y: float, theta: float) -> tuple[float, ...]:
        row = [math.nan] * len(LAW_SIGNALS)
        for i, value in zip(self.at, self.law.update(x, y, theta), strict=True):
            row[i] = value
        return tuple(row)

    def __getattr__(self, name: str) -> Any:  # the law's own state (a phase, its gains)
        return getattr(self.law, name)


def make_controller(spec: LawSpec) -> ServoedController:
    """The law ``spec.controller`` names, with the run's gains, on the two wheel servos."""
    info = get(spec.controller)
    law = info.make(spec, info.checked_gains(dict(spec.controller_gains)))
    if info.signals != LAW_SIGNALS:
        law = _Scattered(law, info.signals)
    return ServoedController(law, spec.gains, spec.limits, spec.params, spec.period_s)


__all__ = [
    "BUILTINS",
    "BUILTIN_NAMES",
    "CONTROLLER_GAINS",
    "ENTRY_POINT_GROUP",
    "RUN_GAINS",
    "ControllerInfo",
    "Gain",
    "LawSpec",
    "check_gains",
    "get",
    "make_controller",
    "names",
]

"""Variable maps: drive a robot FMU made by another tool through our interface names.

A robot FMU exported by Dymola, OpenModelica, Simulink or a hand-written tool has its own
variable names and perhaps its own units.  A map (a TOML file, ``docs/fmu_map.md``) names, for
each of our interface names (the table of ``docs/fmu_map.md``: inputs ``tau_r``, ``tau_l``;
outputs ``x``, ``y``, ``theta``, ...; parameters ``m``, ``r``, ``L``, ..., ``x0``, ``y0``,
``theta0``), the FMU's variable and the affine relation between the two units::

    ours = scale * theirs + offset

for inputs, outputs and parameters alike (so a heading in degrees has
``scale = 0.017453292519943295``).  A name the map does not give is looked up under its own
name in the FMU; an optional name may be listed in ``unmapped`` when the FMU has nothing like
it (an output is then NaN in the log, a parameter keeps the FMU's own value).

:func:`resolve` checks a map against the FMU's model description and returns a
:class:`ResolvedMap` that :class:`wmr.adapters.fmi.robot.FmuPlant` drives; every problem is a
:class:`~wmr.infra.errors.ConfigError` of one line naming the variable and the fix.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from wmr.config.scenario import read_toml
from wmr.core.plant import OUTPUT_NAMES, RobotParams
from wmr.infra.errors import ConfigError

#: Our inputs, in the order :meth:`FmuPlant.step` takes them.
INPUT_NAMES: Final = ("tau_r", "tau_l")
#: Outputs the master loop and the stabiliser cannot do without.
REQUIRED_OUTPUTS: Final = ("x", "y", "theta", "v", "omega", "omega_r", "omega_l")
#: Initial-state parameters: the start pose is required, the initial speeds are optional.
START_PARAMETERS: Final = ("x0", "y0", "theta0", "v0", "omega0")
REQUIRED_PARAMETERS: Final = ("x0", "y0", "theta0")
PARAMETER_NAMES: Final = (*RobotParams().as_dict(), *START_PARAMETERS)
#: Every interface name a map may give.
INTERFACE_NAMES: Final = (*INPUT_NAMES, *OUTPUT_NAMES, *PARAMETER_NAMES)

_ROLE: Final = {**{n: "input" for n in INPUT_NAMES}, **{n: "output" for n in OUTPUT_NAMES},
                **{n: "parameter" for n in PARAMETER_NAMES}}
_REQUIRED: Final = frozenset((*INPUT_NAMES, *REQUIRED_OUTPUTS, *REQUIRED_PARAMETERS))
_FLOAT_TYPES: Final = ("Real", "Float64")


@dataclass(frozen=True)
class MapEntry:
    """One of our names bound to the FMU's variable ``name``: ``ours = scale*theirs + offset``."""

    name: str
    scale: float = 1.0
    offset: float = 0.0

    def to_theirs(self, ours: float) -> float:
        """The FMU's value of ``ours`` (inputs and parameters)."""
        return (ours - self.offset) / self.scale

    def to_ours(self, theirs: float) -> float:
        """Our value of the FMU's ``theirs`` (outputs)."""
        return self.scale * theirs + self.offset


@dataclass(frozen=True)
class VariableMap:
    """A parsed map file, not yet checked against an FMU.

    ``entries`` by our name; ``unmapped`` our optional names the FMU lacks; ``source`` names
    the file in error messages.
    """

    entries: Mapping[str, MapEntry] = field(default_factory=dict)
    unmapped: frozenset[str] = frozenset()
    source: str = "map"

    def to_toml(self) -> str:
        """The map as a map file (:func:`parse_map` reads it back to an equal map)."""
        lines = [f"# variable map ({self.source}): ours = scale * theirs + offset"]
        lines.append("unmapped = [" + ", ".join(f'"{u}"' for u in sorted(self.unmapped)) + "]")
        lines.append("\n[variables]")
        for ours, e in self.entries.items():
            lines.append(f"{ours} = {{ name = {json.dumps(e.name)}, scale = {e.scale!r}, "
                         f"offset = {e.offset!r} }}")
        return "\n".join(lines) + "\n"

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (the ``run`` metadata of a log records it)."""
        return {"variables": {k: {"name": e.name, "scale": e.scale, "offset": e.offset}
                              for k, e in self.entries.items()},
                "unmapped": sorted(self.unmapped), "source": self.source}


def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(where, f"must be a finite number, got {value!r}",
                          "write a plain number")
    return float(value)


def parse_map(data: Mapping[str, Any], source: str = "map") -> VariableMap:
    """Validate a map's parsed TOML (``[variables]`` and ``unmapped``)."""
    for key in data:
        if key not in ("variables", "unmapped"):
            raise ConfigError(f"{source}: {key}", "unknown field",
                              "a map has a [variables] table and an unmapped list")
    table = data.get("variables", {})
    if not isinstance(table, Mapping):
        raise ConfigError(f"{source}: variables", f"must be a table, got {table!r}",
                          "write [variables] with lines like x = \"their_x\"")
    entries: dict[str, MapEntry] = {}
    for ours, value in table.items():
        where = f"{source}: variables.{ours}"
        if ours == "unmapped":
            raise ConfigError(where, "unmapped belongs to the top level, not to [variables]",
                              "move the unmapped = [...] line above [variables]")
        if ours not in _ROLE:
            raise ConfigError(where, "not one of our interface names",
                              f"use one of: {', '.join(INTERFACE_NAMES)}")
        if isinstance(value, str):
            value = {"name": value}
        if not isinstance(value, Mapping):
            raise ConfigError(where, f"must be a name or a table, got {value!r}",
                              f'write {ours} = "their_name" or '
                              f'{ours} = {{ name = "their_name", scale = 1.0 }}')
        for key in value:
            if key not in ("name", "scale", "offset"):
                raise ConfigError(f"{where}.{key}", "unknown field",
                                  "an entry has name, scale and offset")
        name = value.get("name")
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{where}.name", f"must be the FMU's variable name, got {name!r}",
                              "quote the name")
        scale = _number(value.get("scale", 1.0), f"{where}.scale")
        if scale == 0.0:
            raise ConfigError(f"{where}.scale", "must not be 0",
                              "give the factor from their unit to ours, e.g. 0.001 for mm")
        entries[ours] = MapEntry(name, scale, _number(value.get("offset", 0.0),
                                                      f"{where}.offset"))
    unmapped = data.get("unmapped", [])
    if not isinstance(unmapped, list) or not all(isinstance(u, str) for u in unmapped):
        raise ConfigError(f"{source}: unmapped", f"must be a list of names, got {unmapped!r}",
                          'write unmapped = ["phi_r", "phi_l"]')
    for u in unmapped:
        where = f"{source}: unmapped"
        if u not in _ROLE:
            raise ConfigError(where, f"{u!r} is not one of our interface names",
                              f"use one of: {', '.join(INTERFACE_NAMES)}")
        if u in _REQUIRED:
            raise ConfigError(where, f"{u} cannot be left unmapped: the stabiliser needs it",
                              f"map {u} to the FMU's {_ROLE[u]} under [variables]")
        if u in entries:
            raise ConfigError(where, f"{u} is also mapped under [variables]",
                              "remove it from one of the two")
    return VariableMap(entries, frozenset(unmapped), source)


def load_map(path: str | Path) -> VariableMap:
    """Read and validate a map file (TOML)."""
    p = Path(path)
    # the scenarios' reader: bounded, a FIFO or device refused, not UTF-8 and too deep nesting
    # one line each (they were UnicodeDecodeError and RecursionError)
    data, _ = read_toml(p, "--map", fix="give the path of a map TOML file")
    return parse_map(data, source=str(p))


@dataclass(frozen=True)
class ResolvedMap:
    """A map checked against one FMU: for each of our names the FMU's value reference.

    ``outputs`` follows :data:`wmr.core.plant.OUTPUT_NAMES` (``None`` where unmapped);
    ``parameters`` holds only those the FMU has.
    """

    inputs: tuple[tuple[int, MapEntry], ...]
    outputs: tuple[tuple[int, MapEntry] | None, ...]
    parameters: Mapping[str, tuple[int, MapEntry]]

    @property
    def identity(self) -> bool:
        """True when every output is present with scale 1 and offset 0 (the raw fast path)."""
        return all(o is not None and o[1].scale == 1.0 and o[1].offset == 0.0
                   for o in self.outputs)


def _wrong_causality(where: str, ours: str, var: Any, fix_names: list[str]) -> ConfigError:
    role = _ROLE[ours]
    wanted = f"causality '{role}'"
    return ConfigError(
        where, f"the FMU's {var.name!r} has causality '{var.causality}', "
        f"but {ours} is our {role} and needs {wanted}",
        f"map {ours} to one of the FMU's {role}s: {', '.join(fix_names[:12]) or '(none)'}")


def resolve(var_map: VariableMap | None, model_description: Any, fmu_name: str) -> ResolvedMap:
    """Check ``var_map`` (``None``: the identity) against an FMU's model description.

    Raises
    ------
    ConfigError
        An unknown name, a wrong causality or type, or a required name neither mapped nor
        present in the FMU: one line naming the variable and the fix.
    """
    vm = var_map if var_map is not None else VariableMap()
    by_name = {v.name: v for v in model_description.modelVariables}

    def names_of(role: str) -> list[str]:
        return [v.name for v in model_description.modelVariables if v.causality == role]

    def lookup(ours: str) -> tuple[int, MapEntry] | None:
        entry = vm.entries.get(ours)
        role = _ROLE[ours]
        where = f"{vm.source}: variables.{ours}" if entry else f"variable {ours}"
        if entry is None:
            if ours in vm.unmapped:
                return None
            if ours not in by_name:
                if ours not in _REQUIRED:
                    # an optional name the identity map cannot find: say how to drop it
                    raise ConfigError(
                        where, f"{fmu_name} has no {role} named {ours!r} and the map gives none",
                        "map it under [variables] or list it in unmapped = [...]")
                raise ConfigError(
                    where, f"{fmu_name} has no {role} named {ours!r} and the map gives none",
                    f"add {ours} = {{ name = \"...\", scale = 1.0 }} under [variables] naming "
                    f"one of its {role}s: {', '.join(names_of(role)[:12]) or '(none)'}")
            entry = MapEntry(ours)
        var = by_name.get(entry.name)
        if var is None:
            raise ConfigError(where, f"{fmu_name} has no variable {entry.name!r}",
                              f"use one of its {role}s: "
                              f"{', '.join(names_of(role)[:12]) or '(none)'}")
        if var.causality != role:
            raise _wrong_causality(where, ours, var, names_of(role))
        if role == "parameter" and var.variability not in ("fixed", "tunable"):
            raise ConfigError(where, f"the FMU's {var.name!r} has variability "
                              f"'{var.variability}' and cannot be set",
                              "map a fixed or tunable parameter")
        if var.type not in _FLOAT_TYPES:
            raise ConfigError(where, f"the FMU's {var.name!r} is of type {var.type}, but wmr "
                              "exchanges Real (FMI 2) or Float64 (FMI 3) values only",
                              "map a Real/Float64 variable, or wrap the FMU (e.g. with "
                              "fmu-manipulation-toolbox) to convert it")
        if getattr(var, "dimensions", None):
            raise ConfigError(where, f"the FMU's {var.name!r} is an array",
                              "map a scalar variable")
        return var.valueReference, entry

    inputs = []
    for n in INPUT_NAMES:
        found = lookup(n)
        assert found is not None  # required names are never unmapped (parse_map)
        inputs.append(found)
    if inputs[0][0] == inputs[1][0]:
        raise ConfigError(f"{vm.source}: variables.tau_l", "tau_r and tau_l name the same "
                          "FMU variable", "map each torque to its own input")
    outputs = tuple(lookup(n) for n in OUTPUT_NAMES)
    params = {n: p for n in PARAMETER_NAMES if (p := lookup(n)) is not None}
    return ResolvedMap(tuple(inputs), outputs, params)


__all__ = ["INTERFACE_NAMES", "MapEntry", "ResolvedMap", "VariableMap", "load_map",
           "parse_map", "resolve"]

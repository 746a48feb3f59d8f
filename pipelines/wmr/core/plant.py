"""The plant seen by a co-simulation master: anything that advances the robot by one step.

Two implementations exist: :class:`wmr.adapters.fmi.robot.FmuPlant` (the FMU through fmpy, the real
thing) and :class:`wmr.core.physics.ReferencePlant` (a hand-written second implementation of the
same physics, for tests).  The master loop only knows this protocol.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Final, Protocol

import numpy as np
import numpy.typing as npt

from wmr.infra.errors import ConfigError

#: Output variables of the FMU, in the order a plant returns them (see :mod:`wmr.core.signals`).
OUTPUT_NAMES: Final = (
    "x",
    "y",
    "theta",
    "v",
    "omega",
    "omega_r",
    "omega_l",
    "phi_r",
    "phi_l",
    "x_G",
    "y_G",
    "E_kin",
)


@dataclass(frozen=True)
class RobotParams:
    """Physical parameters of the robot (paper, Section 5), SI units.

    The field names are the FMU's parameter names.
    """

    m: float = 25.0  # kg, platform without wheels
    r: float = 0.15  # m, wheel radius
    L: float = 0.3  # m, HALF the track (eq. 2)
    l: float = 0.35  # m, |BG|  # noqa: E741 - the paper's name
    Ig: float = 0.25  # kg m^2, platform about G
    Iwm: float = 0.01  # kg m^2, wheel plus rotor
    b_f: float = 0.0  # N m s/rad, viscous motor friction
    tau_c: float = 0.0  # N m, Coulomb motor friction
    w_c: float = 0.01  # rad/s, tanh smoothing speed of the Coulomb friction

    def __post_init__(self) -> None:
        lower = {"m": 0.0, "r": 1e-3, "L": 1e-3, "Ig": 0.0, "Iwm": 0.0, "b_f": 0.0,
                 "tau_c": 0.0, "w_c": 1e-6}
        #: bounds that exclude their value, with the physical reason
        strict = {"m": "a platform without mass has no dynamics (eq. 24 needs m > 0)"}
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, int | float) or not math.isfinite(value):
                raise ConfigError(f"params.{f.name}", f"must be a finite number, got {value!r}")
            if f.name in strict and value <= lower[f.name]:
                raise ConfigError(f"params.{f.name}",
                                  f"must be > {lower[f.name]:g}, got {value!r}: "
                                  f"{strict[f.name]}", "give a positive value")
            if f.name in lower and value < lower[f.name]:
                raise ConfigError(f"params.{f.name}",
                                  f"must be >= {lower[f.name]:g}, got {value!r}")

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}  # no deep copies


@dataclass(frozen=True)
class Pose:
    """A planar pose of B: position in m, heading in rad."""

    x_m: float
    y_m: float
    heading_rad: float


class Plant(Protocol):
    """A robot that a master advances by fixed control periods."""

    def reset(self, params: RobotParams, start: Pose, v0_mps: float = 0.0,
              omega0_radps: float = 0.0) -> npt.NDArray[np.float64]:
        """Start a new run at t = 0; return the outputs (:data:`OUTPUT_NAMES`) at t = 0."""
        ...

    def step(self, tau_r_nm: float, tau_l_nm: float, h_s: float) -> npt.NDArray[np.float64]:
        """Hold the torques for ``h_s`` seconds; return the outputs at the end of the step.

        The returned array may be reused by the next call: copy it to keep it.
        """
        ...

    def close(self) -> None:
        """Free the plant's resources."""
        ...

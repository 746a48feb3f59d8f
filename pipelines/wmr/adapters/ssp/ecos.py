"""``wmr ssp run --master ecos``: an SSP package in Ecos (``ecospy``), FMI 2.0 and FMI 3.0.

Ecos (Easy co-simulation, NTNU Aalesund) is a fixed-step co-simulation master in C++ whose FMI
layer (fmi4c) loads FMI 1.0, 2.0 and 3.0 FMUs; it reads an SSP 1.0 package with its parameter
sets.  It is the master of the FMI 3.0 closed loop: libcosim loads FMI 2.0 only.  Its timing
is libcosim's (Jacobi, the controller's first sample passed at initialisation;
:mod:`wmr.adapters.ssp.cosim`), but its values are read after it has passed the outputs on to
the inputs: a log row ``k`` holds the robot at ``t_k`` and the controller's sample there, the
layout of ``wmr run``.  It applies the package's parameter sets only when their name is given
to its ``init`` (:func:`_parameter_set_name`); every parameter is checked after it.

ecospy's wheel carries ``libecosc.so`` but not the oneTBB library it links against
(``libtbb.so.12``): the ``tbb`` wheel installs it into the environment's ``lib`` folder, which
the loader does not search, so it is loaded first by path.
"""

from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wmr.adapters.fmi.varmap import MapEntry
from wmr.adapters.ssp.cosim import (
    CONTROL_OUTPUTS,
    SspRunData,
    c_stdout_to_stderr,
    log_rows,
    n_steps,
    step_size,
)
from wmr.adapters.ssp.package import CONTROLLER, ROBOT, SspPackage, unpacked_package
from wmr.core.plant import OUTPUT_NAMES
from wmr.infra.errors import ConfigError, FmuError


def _ecospy() -> Any:
    """The ``ecospy`` module, with oneTBB loaded first from the environment if it is there."""
    if sys.platform.startswith("linux"):
        tbb = Path(sys.prefix) / "lib" / "libtbb.so.12"
        if tbb.exists():
            ctypes.CDLL(str(tbb), mode=ctypes.RTLD_GLOBAL)
    try:
        import ecospy
    except ImportError:
        raise ConfigError("ecospy", "not installed: wmr ssp run --master ecos needs Ecos",
                          "pip install 'wmr-cosim[ssp]'") from None
    except OSError as exc:  # the shared library or one it needs is missing
        raise ConfigError("ecospy", f"its library does not load ({exc})",
                          "pip install tbb (oneTBB, which Ecos links against)") from None
    return ecospy


def ecos_version() -> str:
    """``ecospy <version>`` of the installed package."""
    from importlib.metadata import version

    return f"ecospy {version('ecospy')}"


def recorded_names(package: SspPackage) -> dict[str, list[str]]:
    """Each component's variables (its own names) that the log and the energies need."""
    vm = package.robot_map
    robot = []
    for n in (*OUTPUT_NAMES, "tau_r", "tau_l"):
        if vm is not None and n in vm.unmapped:
            continue
        robot.append(vm.entries.get(n, MapEntry(n)).name if vm is not None else n)
    return {ROBOT: robot, CONTROLLER: [*CONTROL_OUTPUTS, "converged"]}


def _parameter_set_name(folder: Path, package: SspPackage) -> str:
    """The name of the package's parameter sets (``wmr ssp export`` gives both the run's).

    Ecos applies an SSD's ``ParameterBinding`` only when its ``ParameterSet`` is named to
    ``init``; without a name it runs the FMUs' defaults, silently.
    """
    import xml.etree.ElementTree as ET

    names = {ET.parse(ssv).getroot().get("name", "") for ssv in sorted(folder.rglob("*.ssv"))}
    if len(names) != 1 or "" in names:
        raise FmuError(f"{package.path}: Ecos applies one named parameter set, the package has "
                       f"{sorted(names)}: export it again with 'wmr ssp export'")
    return names.pop()


def _check_parameters(package: SspPackage, get: Any) -> None:
    """Every parameter of the package's sets is what Ecos gave the FMU."""
    for comp in (ROBOT, CONTROLLER):
        for name, value in package.component(comp).parameters.items():
            got = get(f"{comp}::{name}")
            if abs(got - value) > 1e-12 * max(1.0, abs(value)):
                raise FmuError(f"{package.path}: Ecos did not apply the parameter set: "
                               f"{comp}.{name} is {got:g}, the package says {value:g}")


def simulate_ecos(ssp_path: str | os.PathLike[str], *, stop_time_s: float | None = None,
                  stop_at_convergence: bool = True) -> SspRunData:
    """Run a package of ``wmr ssp export`` (FMI 2.0 or 3.0) in Ecos.

    Parameters
    ----------
    ssp_path
        The ``.ssp`` file.
    stop_time_s
        End of the run, s; default the package's default experiment (``max_time_s``).
    stop_at_convergence
        End at the first sample whose ``converged`` output is 1, like ``wmr run``.

    Raises
    ------
    ConfigError, FmuError
        ecospy is missing, the package is missing or incomplete, or Ecos refuses it or fails
        a step.
    """
    ecospy = _ecospy()
    # Ecos gets the folder we extracted and checked, never the package itself
    with unpacked_package(ssp_path) as (package, folder):
        return _simulate(ecospy, package, folder, stop_time_s, stop_at_convergence)


def _simulate(ecospy: Any, package: SspPackage, folder: Path, stop_time_s: float | None,
              stop_at_convergence: bool) -> SspRunData:
    h = step_size(package)
    n_max = n_steps(package, h, stop_time_s)
    names = recorded_names(package)
    values: dict[str, dict[str, list[float]]] = {c: {n: [] for n in names[c]} for c in names}
    ecospy.EcosLib.set_log_level("warn")
    steps = 0
    with c_stdout_to_stderr():
        try:
            sim = ecospy.EcosSimulation(h, ssp_path=str(folder))
        except Exception as exc:  # ecospy raises a bare Exception with the library's message
            raise FmuError(f"{package.path}: Ecos cannot load the package: {exc}") from None
        try:
            if not sim.init(package.start_time_s, _parameter_set_name(folder, package)):
                raise FmuError(f"{package.path}: Ecos failed to initialise the package (an "
                               "FMU returned an error)")
            get = sim.get_real
            _check_parameters(package, get)

            def record() -> None:
                for comp, columns in values.items():
                    for n, column in columns.items():
                        column.append(get(f"{comp}::{n}"))

            record()
            while steps < n_max:
                sim.step(1)
                steps += 1
                record()
                if stop_at_convergence and values[CONTROLLER]["converged"][-1] >= 0.5:
                    break
            sim.terminate()
        except FmuError:
            raise
        except Exception as exc:
            raise FmuError(f"{package.path}: Ecos failed at t = {steps * h:g} s: {exc}") \
                from None
        finally:
            sim.free()
    variables: dict[str, dict[str, npt.NDArray[np.float64]]] = {
        c: {n: np.asarray(v, dtype=np.float64) for n, v in cols.items()}
        for c, cols in values.items()}
    # Ecos reads after it has passed the outputs on: the log rows of wmr run's layout
    return log_rows(package, variables, steps, h, stop_at_convergence, ecos_version(),
                    after_transfer=True)

__all__ = ["ecos_version", "recorded_names", "simulate_ecos"]

"""``wmr fmu crosscheck``: our FMUs in the layout of the FMI Cross-Check rules (version 4.1).

For every FMU, interface and platform it carries::

    fmus/<FMI version>/<cs|me>/<platform>/wmr-cosim/<version>/wmr_robot/
        wmr_robot.fmu  wmr_robot_in.csv  wmr_robot_ref.csv  wmr_robot_ref.opt  ReadMe.md

so that another tool can import the FMU with the inputs and compare its result with ours, and::

    results/<FMI version>/<cs|me>/<host platform>/FMPy/<fmpy version>/wmr-cosim/<version>/
        wmr_robot/passed   (or failed, with ReadMe.md saying why)

for fmpy re-importing the FMU with the inputs and comparing against the reference by fmpy's
cross-check validation.  The reference results are our FMU simulated by fmpy on this machine.
The rules name FMI 1.0 and 2.0 and the FMI 2 platform names only; the FMI 3.0 entries follow the
same layout with FMI 3 platform tuples and carry ``notCompliantWithLatestRules`` saying so.
"""

from __future__ import annotations

import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wmr.build.fmus import BuildResult, summarize
from wmr.build.platforms import host_platform
from wmr.infra.errors import BuildError
from wmr.infra.version import __version__

TOOL = "wmr-cosim"
MODEL = "wmr_robot"
START_S, STOP_S, STEP_S = 0.0, 10.0, 0.01
#: The FMU's own solver tolerance (fmu/src/README.md); the references are made without setting
#: one, so that an importer that sets none reproduces them to rounding.
REL_TOL = 1e-9
#: The model-exchange reference's CVode tolerance: restarted at every input change, it is then
#: the exact hold-input solution to about 3e-10 relative (tests/test_fmu_crosscheck.py, against
#: SciPy's DOP853 on :mod:`wmr.core.physics`); at 1e-9 it was 1e-6.
ME_REL_TOL = 1e-13
#: The outputs in the reference (the rules recommend at most 10 variables).
REFERENCE_OUTPUTS = ("x", "y", "theta", "v", "omega", "omega_r", "omega_l", "phi_r", "phi_l",
                     "E_kin")
#: Input breakpoints (time s, tau_r N.m, tau_l N.m), linearly interpolated as the rules say:
#: a spin-up, a turn, a reversal and a coast, so that every output moves.
INPUT_POINTS = ((0.0, 0.0, 0.0), (2.0, 1.0, 0.6), (4.0, 1.0, 1.0), (6.0, -0.5, 0.5),
                (8.0, 0.2, -0.2), (10.0, 0.0, 0.0))
_INTERFACE = {"co-simulation": ("cs", "CoSimulation"), "model exchange": ("me", "ModelExchange")}


@dataclass(frozen=True)
class CrossCheckEntry:
    """One exported-FMU folder and what fmpy made of re-importing it."""

    folder: Path
    fmi_version: str
    fmi_type: str  # "cs" or "me"
    platform: str
    #: fmpy's re-import of the host platform's entry; None for the other platforms.
    passed: bool | None


def input_signal() -> np.ndarray:
    """The input trajectory as fmpy's structured array (``time``, ``tau_r``, ``tau_l``)."""
    dtype = np.dtype([("time", np.float64), ("tau_r", np.float64), ("tau_l", np.float64)])
    return np.array(list(INPUT_POINTS), dtype=dtype)


def output_times() -> np.ndarray:
    """The output points ``START_S + k STEP_S``, computed as fmpy computes its grid."""
    n = round((STOP_S - START_S) / STEP_S)
    return START_S + np.arange(n + 1) * STEP_S


def held_input(signal: np.ndarray) -> np.ndarray:
    """``signal`` sampled at the output points and held until the next one: a staircase, each
    step a repeated time (the value before and after), which fmpy treats as an input event.

    The input both references hold (docs/fmu.md).  Given to fmpy's model exchange, each event
    enters event mode and restarts CVode with the new input: without them CVode integrated
    past each output point with the old input (the robot moved from 0.04 s, not 0.02 s) and
    the reference was 5 mm off the hold-input solution.
    """
    names = signal.dtype.names
    assert names is not None
    t = output_times()
    held = {n: np.interp(t, signal[names[0]], signal[n]) for n in names[1:]}
    rows = np.empty(2 * len(t) - 1, dtype=signal.dtype)
    rows[names[0]] = np.repeat(t, 2)[1:]  # t0, t1, t1, t2, t2, ...
    for n in names[1:]:
        rows[n] = np.repeat(held[n], 2)[:-1]  # u0, u0, u1, u1, u2, ...
    return rows


def simulate(fmu: Path, fmi_type: str, signal: np.ndarray) -> np.ndarray:
    """Simulate ``fmu`` with fmpy over the reference interval and return the reference outputs.

    Co-simulation: fmpy sets the interpolated inputs at each communication point (STEP_S).
    Model exchange: the same inputs held over each output interval (:func:`held_input`), CVode
    at ``ME_REL_TOL`` restarted at each output point: the exact hold-input solution.
    """
    from fmpy import simulate_fmu

    me = fmi_type == "me"
    result = simulate_fmu(
        str(fmu), start_time=START_S, stop_time=STOP_S, fmi_type=_fmpy_type(fmi_type),
        step_size=STEP_S, output_interval=STEP_S, input=held_input(signal) if me else signal,
        output=list(REFERENCE_OUTPUTS), solver="CVode",
        relative_tolerance=ME_REL_TOL if me else None, record_events=False)
    return np.asarray(result)


def _fmpy_type(fmi_type: str) -> str:
    return next(t for short, t in _INTERFACE.values() if short == fmi_type)


def _ref_opt(fmi_type: str) -> str:
    tol = ME_REL_TOL if fmi_type == "me" else REL_TOL
    return (f"StartTime, {START_S!r}\nStopTime, {STOP_S!r}\nStepSize, {STEP_S!r}\n"
            f"RelTol, {tol!r}\n")


def _readme(fmi_version: str, fmi_type: str, platform: str, host: str) -> str:
    import fmpy

    interface = "co-simulation" if fmi_type == "cs" else "model exchange"
    how = (f"fmpy {fmpy.__version__} drove the FMU with `{MODEL}_in.csv` (inputs set at each "
           f"communication point, linearly interpolated), communication step {STEP_S} s, no "
           "tolerance set (the FMU's own Dormand-Prince solver then uses rtol 1e-9)"
           if fmi_type == "cs" else
           f"fmpy {fmpy.__version__} integrated the FMU with CVode at rtol {ME_REL_TOL}, the "
           f"inputs of `{MODEL}_in.csv` taken at each output point (every {STEP_S} s) and held "
           "until the next, the integrator restarted at each: the exact solution under those "
           "held inputs")
    where = ("on this platform" if platform == host else
             f"on {host}; the project's tests run the aarch64-linux binary under qemu-aarch64 "
             "and the win64 binary under wine and find the x86_64-linux result to 1e-12 "
             "(the darwin binaries are checked for format, architecture and exports only)")
    return f"""# {MODEL}: wmr-cosim {__version__}, FMI {fmi_version} {interface}, {platform}

The two-wheeled differential-drive robot of Bunjaku, Stefanovski and Stankovski (dynamics with
wheel and motor inertia and friction, the paper's errata corrected); the FMU's
`documentation/index.html` has its equations and variables.

## Reference result

`{MODEL}_ref.csv` was computed {where}: {how}. Inputs: `tau_r`, `tau_l` (N.m). Outputs:
{", ".join(f"`{n}`" for n in REFERENCE_OUTPUTS)}. `E_kin` is conserved whenever the torques
are zero and friction is off, an independent check of the result.

An importer that reproduces this setup should agree to about 1e-9 relative (co-simulation: to
rounding, about 1e-12). Model exchange: hold the inputs over each output interval and restart
(or stop) the integrator at each output point, where the input changes; an integrator that
steps past an output point with the old input is millimetres off.

## Exporting tool

wmr-cosim {__version__} (`wmr fmu build`, `wmr fmu crosscheck`); BSD-2-Clause.
"""


def write_crosscheck(build: BuildResult, out_dir: Path) -> list[CrossCheckEntry]:
    """Write the cross-check tree for the FMUs of ``build`` into ``out_dir``.

    Raises
    ------
    BuildError
        When this machine cannot run the FMU (no binary for the host platform).
    """
    import fmpy
    from fmpy.cross_check import validate_result
    from fmpy.util import read_csv, write_csv

    host = host_platform()
    if host is None:
        raise BuildError("the cross-check references are simulated here, but the FMUs have no "
                         "binary for this platform")
    signal = input_signal()
    entries: list[CrossCheckEntry] = []
    for fmu in build.fmus.values():
        summary = summarize(fmu)
        fmi_version = summary.fmi_version
        major = int(fmi_version[0])
        host_folder = host.folder(major)
        if host_folder not in summary.platforms:
            raise BuildError(f"{fmu.name} has no {host.name} binary to make the references with")
        for interface in summary.interfaces:
            if interface not in _INTERFACE:
                continue
            fmi_type = _INTERFACE[interface][0]
            reference = simulate(fmu, fmi_type, signal)
            for platform in summary.platforms:
                folder = (out_dir / "fmus" / fmi_version / fmi_type / platform / TOOL
                          / __version__ / MODEL)
                if folder.exists():
                    shutil.rmtree(folder)
                folder.mkdir(parents=True)
                shutil.copyfile(fmu, folder / f"{MODEL}.fmu")
                write_csv(folder / f"{MODEL}_in.csv", signal)
                write_csv(folder / f"{MODEL}_ref.csv", reference)
                (folder / f"{MODEL}_ref.opt").write_text(_ref_opt(fmi_type))
                (folder / "ReadMe.md").write_text(
                    _readme(fmi_version, fmi_type, platform, str(host_folder)))
                if major >= 3:
                    (folder / "notCompliantWithLatestRules").write_text(
                        "The FMI Cross-Check rules 4.1 name FMI 1.0 and 2.0 and the FMI 2 "
                        "platform names only; this FMI 3.0 entry follows their layout with the "
                        "FMI 3 platform tuple.\n")
                passed: bool | None = None
                if platform == host_folder:
                    # fmpy re-imports what another tool would get and compares to our reference.
                    again = simulate(folder / f"{MODEL}.fmu", fmi_type,
                                     read_csv(folder / f"{MODEL}_in.csv"))
                    with warnings.catch_warnings():
                        # fmpy 0.3.32 imports scipy.ndimage.filters, deprecated in SciPy.
                        warnings.simplefilter("ignore", DeprecationWarning)
                        problem = validate_result(again, read_csv(folder / f"{MODEL}_ref.csv"),
                                                  START_S, STOP_S)
                    passed = not problem
                    result_dir = (out_dir / "results" / fmi_version / fmi_type / platform
                                  / "FMPy" / fmpy.__version__ / TOOL / __version__ / MODEL)
                    if result_dir.exists():
                        shutil.rmtree(result_dir)
                    result_dir.mkdir(parents=True)
                    (result_dir / ("passed" if passed else "failed")).write_text("")
                    if problem:
                        (result_dir / "ReadMe.md").write_text(f"fmpy: {problem}\n")
                entries.append(CrossCheckEntry(folder, fmi_version, fmi_type, platform, passed))
    return entries

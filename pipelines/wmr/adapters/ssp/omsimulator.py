"""An SSP package in OMSimulator (OpenModelica), through its Python package ``OMSimulator``.

OMSimulator is not on the package registries in a form that installs here (its PyPI releases
download binaries at install time): a machine that has it built it from source and put its
Python package (which loads ``libOMSimulator.so``) on ``PYTHONPATH`` (docs/ssp.md,
"OMSimulator").  Nothing of it is imported before :func:`simulate_omsimulator` is called.

The run is the one a user of its Python API makes: ``SSP(package)``, ``instantiate()`` (it
applies the SSD's parameter bindings), a result file, the package's step and stop time,
``initialize()``, ``simulate()`` to the stop time, ``terminate()``, ``delete()``.  Its Python
layer reads no SSD annotation (``utils.parseDefaultExperiment``: "TODO parse ssd:annotation"),
so the package's step is given as the API gives it (``setStepSize``, the maximum step of its
fixed-step master ``oms-ma``).  It runs to the stop time: at this version it stops a run only
when an FMU's ``doStep`` returns Discard, not on ``fmi2Terminated`` or FMI 3's
``terminateSimulation`` (``ComponentFMUCS::stepUntil``, ``ComponentFMU3CS::stepUntil``).

Timing.  Its master steps the FMUs side by side to ``t_(k+1)``, writes a result row, passes
the outputs on to the inputs in the order of its dependency graph, and writes a second row at
the same time (``SystemWC::doStep``).  The second row of each time is kept: the robot at
``t_k`` and the controller's sample there on the measurement just passed, the layout of ``wmr
run``'s rows (``after_transfer`` of :func:`wmr.adapters.ssp.cosim.log_rows`).

OMSimulator gets a plain archive of the members :func:`unpacked_package` checked, never the
stranger's zip, and writes its result file, log and temporary files in our private folder.
"""

from __future__ import annotations

import csv
import io
import os
import re
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from wmr.adapters.ssp.cosim import SspRunData, c_stdout_to_stderr, log_rows, step_size
from wmr.adapters.ssp.ecos import recorded_names
from wmr.adapters.ssp.package import CONTROLLER, SspPackage, unpacked_package
from wmr.infra.errors import ConfigError, FmuError

#: The Python package OMSimulator's build installs (``lib/OMSimulator`` of its prefix).
MODULE: Final = "OMSimulator"
#: OMSimulator's result file of a 120 s run at 10 ms holds about 2 MB; a bigger one is refused.
MAX_RESULT_BYTES: Final = 256 * (1 << 20)
#: What OMSimulator's Python layer says of an FMI 3.0 FMU up to v3.0.0-108
#: (``src/OMSimulatorPython/fmu.py``, ``FMU._parse_variables``: it reads
#: ``//ModelVariables/ScalarVariable``, FMI 2.0's layout; FMI 3.0's from v3.0.0-109, c8a95f54).
FMI3_REFUSAL: Final = "ModelVariables section not found in modelDescription.xml"
#: The last lines of OMSimulator's log kept to say why it failed.
_LOG_TAIL_BYTES: Final = 64 * 1024


def omsimulator() -> Any:
    """The ``OMSimulator`` module (it loads ``libOMSimulator.so`` on import).

    Raises
    ------
    ConfigError
        It is not importable here, or its library does not load: the message says which.
    """
    try:
        import OMSimulator
    except ImportError as exc:
        raise ConfigError("OMSimulator", f"not importable: {exc}",
                          "build it from source and put its lib folder on PYTHONPATH "
                          "(docs/ssp.md, 'OMSimulator')") from None
    except OSError as exc:  # libOMSimulator.so or a library it needs is missing
        raise ConfigError("OMSimulator", f"not importable: its library does not load ({exc})",
                          "build it again (docs/ssp.md, 'OMSimulator')") from None
    return OMSimulator


def omsimulator_version() -> str:
    """``OMSimulator <version>`` as its library reports it (``oms_getVersion``)."""
    return str(omsimulator().version)


def simulate_omsimulator(ssp_path: str | os.PathLike[str], *,
                         stop_time_s: float | None = None) -> SspRunData:
    """Run a package of ``wmr ssp export`` in OMSimulator to its stop time.

    Parameters
    ----------
    ssp_path
        The ``.ssp`` file.
    stop_time_s
        End of the run, s; default the package's default experiment (``max_time_s``).

    Returns
    -------
    SspRunData
        Every communication point ``0 .. steps`` of the run (``time_to_goal_s`` is ``None``:
        it ran to the stop time; the controller's ``converged`` output is in ``variables``).

    Raises
    ------
    ConfigError
        OMSimulator is not importable, or the package is missing or has no stop time.
    FmuError
        The package is refused, or OMSimulator cannot load or run it (its error in one line).
    """
    oms = omsimulator()
    with unpacked_package(ssp_path) as (package, folder):
        stop = stop_time_s if stop_time_s is not None else package.stop_time_s
        if stop is None:
            raise ConfigError("SSP", f"{package.path} has no stop time (no "
                              "DefaultExperiment stopTime)", "export it again with 'wmr ssp "
                              "export'")
        h = step_size(package)
        work = folder.parent / "omsimulator"
        work.mkdir()
        result = work / "result.csv"
        names = recorded_names(package)
        with _oms_run(oms, package, folder, work) as model:
            model.setResultFile(str(result))
            # the signals compared, not the 50 of both FMUs (18 MB for Fig. 11's 120 s)
            model.removeSignalsFromResults(".*")
            model.addSignalsToResults(_signals_regex(names))
            model.setStartTime(package.start_time_s)
            model.setStopTime(stop)
            model.setStepSize(h)
            _call(model.initialize, "initialize", package, work)
            _call(model.simulate, "simulate", package, work)
        times, variables = read_result(result, names, package)
        steps = len(times) - 1
        expected = max(1, round((stop - package.start_time_s) / h))
        grid = package.start_time_s + h * np.arange(steps + 1)
        if steps != expected or not np.allclose(times, grid, rtol=0.0, atol=h * 1e-6):
            raise FmuError(f"{package.path}: OMSimulator's result has {steps} steps to t = "
                           f"{times[-1]:g} s, not {expected} steps of {h:g} s to {stop:g} s")
        return log_rows(package, variables, steps, h, False, str(oms.version),
                        after_transfer=True)


def _signals_regex(names: dict[str, list[str]]) -> str:
    """A regular expression (C++ ``std::regex``, matched against the whole name) of the
    signals ``<system>.<component>.<variable>`` of ``names``."""
    alternatives = [f"{re.escape(c)}\\.{re.escape(n)}" for c, ns in names.items() for n in ns]
    return f".*\\.({'|'.join(alternatives)})"


@contextmanager
def _oms_run(oms: Any, package: SspPackage, folder: Path, work: Path) -> Iterator[Any]:
    """OMSimulator's instantiated model of the checked package (deleted on exit), its log in
    ``work/omsimulator.log`` and what its C code prints on standard error."""
    archive = work / "package.ssp"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(folder).as_posix())
    with c_stdout_to_stderr():
        oms.Capi.setLogFile(str(work / "omsimulator.log"))
        try:
            ssp = oms.SSP(str(archive), temp_dir=str(work / "ssp"))
            model = ssp.instantiate()
        except Exception as exc:  # its Python layer raises bare Exceptions and RuntimeErrors
            raise FmuError(f"{package.path}: OMSimulator cannot load the package: "
                           f"{_why(exc, work)}") from None
        try:
            yield model
            _call(model.terminate, "terminate", package, work)
        finally:
            model.delete()
            oms.Capi.setLogFile("")


def _call(step: Any, what: str, package: SspPackage, work: Path) -> None:
    try:
        step()
    except RuntimeError as exc:
        raise FmuError(f"{package.path}: OMSimulator failed to {what} the package: "
                       f"{_why(exc, work)}") from None


def _why(exc: Exception, work: Path) -> str:
    """The exception's first line, with the last error OMSimulator logged (its Python layer
    reports only a status)."""
    line = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    log = work / "omsimulator.log"
    if log.is_file():
        with log.open("rb") as f:
            f.seek(max(0, log.stat().st_size - _LOG_TAIL_BYTES))
            tail = f.read().decode("utf-8", "replace").splitlines()
        errors = [x.strip() for x in tail if x.lstrip().startswith("error:")]
        if errors:
            return f"{line} ({errors[-1]})"
    return line


def read_result(path: Path, names: dict[str, list[str]], package: SspPackage
                ) -> tuple[npt.NDArray[np.float64], dict[str, dict[str, npt.NDArray[np.float64]]]]:
    """The times and ``names[component]`` columns of OMSimulator's CSV result file.

    OMSimulator writes a ``"sep=,"`` line, a header ``time,<signal>,...`` and rows of
    ``%.12g`` values; it names a signal ``<system>.<component>.<variable>``.  Where it wrote
    two rows at one time (before and after passing values on), the second is kept.

    Raises
    ------
    FmuError
        The file is missing, too big, or lacks a column.
    """
    if not path.is_file():
        raise FmuError(f"{package.path}: OMSimulator wrote no result file")
    size = path.stat().st_size
    if size > MAX_RESULT_BYTES:
        raise FmuError(f"{package.path}: OMSimulator's result file has {size} bytes, more "
                       f"than {MAX_RESULT_BYTES}")
    with path.open(encoding="utf-8", newline="") as f:
        text = f.read(MAX_RESULT_BYTES + 1)
    reader = csv.reader(io.StringIO(text), skipinitialspace=True)
    header = next(reader, [])
    if header == ["sep=,"]:
        header = next(reader, [])
    rows = np.array([[float(v) for v in row] for row in reader if row], dtype=np.float64)
    if not header or header[0] != "time" or rows.ndim != 2 or rows.shape[1] != len(header):
        raise FmuError(f"{package.path}: OMSimulator's result file is not its CSV layout "
                       f"(header {header[:3]}...)")
    last = np.append(rows[1:, 0] != rows[:-1, 0], True)  # the last row of each time
    rows = rows[last]
    variables: dict[str, dict[str, npt.NDArray[np.float64]]] = {}
    for component, wanted in names.items():
        variables[component] = {}
        for name in wanted:
            suffix = f".{component}.{name}"
            cols = [i for i, h in enumerate(header)
                    if h.endswith(suffix) or h == suffix[1:]]
            if len(cols) != 1:
                raise FmuError(f"{package.path}: OMSimulator's result file has "
                               f"{len(cols)} columns of {component}.{name}, not 1")
            variables[component][name] = rows[:, cols[0]]
    return rows[:, 0], variables


def converged_at_s(run: SspRunData) -> float | None:
    """The time of the first sample whose ``converged`` output is 1 (``None``: none is)."""
    flags = run.variables[CONTROLLER]["converged"]
    hit = np.flatnonzero(flags >= 0.5)
    return float(hit[0] * run.step_size_s) if hit.size else None


__all__ = ["FMI3_REFUSAL", "MODULE", "converged_at_s", "omsimulator", "omsimulator_version", "read_result",
           "simulate_omsimulator"]

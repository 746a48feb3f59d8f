"""An SSP package in OMSimulator (OpenModelica), through its Python package ``OMSimulator``.

OMSimulator is not on the package registries in a form that installs here (its PyPI releases
download binaries at install time): a machine that has it built it from source and put its
Python package (which loads ``libOMSimulator.so``) on ``PYTHONPATH`` (docs/ssp.md,
"OMSimulator").  Nothing of it is imported before :func:`simulate_omsimulator` is called.

The run is OMSimulator's own import of an SSP package, ``oms_importFile`` (what its command
line ``OMSimulator PKG.ssp`` does), called through the library its Python package loaded
(``OMSimulator.Capi``), then ``oms_setResultFile`` (CSV), ``oms_setStopTime`` (the package's),
``oms_instantiate``, ``oms_initialize``, ``oms_simulate``, ``oms_terminate``, ``oms_delete``.
That import reads the package's ``oms:FixedStepMaster`` annotation (the system's type, the
step, the relative tolerance) and its parameter bindings, and loads FMI 2.0 and FMI 3.0
co-simulation FMUs.  The Python package's own SSP reader (``OMSimulator.SSP``) at this version
(3.0.0.post103) reads no SSD annotation and no FMI 3.0 model description ("ModelVariables
section not found in modelDescription.xml", ``src/OMSimulatorPython/fmu.py``), so it is not
used.  Two limits of OMSimulator are worked around and said in docs/ssp.md: it names its
model after the SSD and takes identifiers only (:func:`model_name`), and it sees an algebraic
loop in an FMI 3.0 package (:data:`ALG_LOOP_SOLVER`).  It runs to the stop time: at this
version it stops a run only when an FMU's ``doStep`` returns Discard, not on
``fmi2Terminated`` or FMI 3's ``terminateSimulation`` (``ComponentFMUCS::stepUntil``,
``ComponentFMU3CS::stepUntil``).

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
import ctypes
import importlib
import io
import os
import re
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from wmr.adapters.fmi.archive import parse_xml
from wmr.adapters.ssp.cosim import SspRunData, c_stdout_to_stderr, log_rows, step_size
from wmr.adapters.ssp.ecos import recorded_names
from wmr.adapters.ssp.export import SSD_NAME
from wmr.adapters.ssp.package import CONTROLLER, SspPackage, unpacked_package
from wmr.infra.errors import ConfigError, FmuError

#: The Python package OMSimulator's build installs (``lib/OMSimulator`` of its prefix).
MODULE: Final = "OMSimulator"
#: OMSimulator's result file (a few MB for a 120 s run at 10 ms): a bigger one is refused.
MAX_RESULT_BYTES: Final = 256 * (1 << 20)
#: OMSimulator's solver of algebraic loops between components, set for every run.
ALG_LOOP_SOLVER: Final = "fixedpoint"
_IDENT: Final = re.compile(r"[a-zA-Z][a-zA-Z0-9_]*")
#: ``oms_status_warning``: a status above it is an error.
_WARNING: Final = 1
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
        return importlib.import_module(MODULE)
    except ImportError as exc:
        raise ConfigError("OMSimulator", f"not importable: {exc}",
                          "build it from source and put its lib folder on PYTHONPATH "
                          "(docs/ssp.md, 'OMSimulator')") from None
    except OSError as exc:  # libOMSimulator.so or a library it needs is missing
        raise ConfigError("OMSimulator", f"not importable: its library does not load ({exc})",
                          "build it again (docs/ssp.md, 'OMSimulator')") from None


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
        it ran to the stop time; the controller's ``converged`` output is in ``variables``);
        ``extra["model_name"]``: the name OMSimulator's model had (:func:`model_name`).

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
        with _imported(oms, package, folder, work) as (model, call):
            call("setResultFile", model, str(result))
            # the signals compared, not the 50 of both FMUs (18 MB for Fig. 11's 120 s)
            call("removeSignalsFromResults", model, ".*")
            call("addSignalsToResults", model, _signals_regex(names))
            call("setStopTime", model, stop)
            for step in ("instantiate", "initialize", "simulate", "terminate"):
                call(step, model)
        times, variables = read_result(result, names, package)
        steps = len(times) - 1
        expected = max(1, round((stop - package.start_time_s) / h))
        grid = package.start_time_s + h * np.arange(steps + 1)
        if steps != expected or not np.allclose(times, grid, rtol=0.0, atol=h * 1e-6):
            # its step is the package's oms:FixedStepMaster stepSize: a package without it is
            # stepped at OMSimulator's default, 1 ms
            raise FmuError(f"{package.path}: OMSimulator's result has {steps} steps to t = "
                           f"{times[-1]:g} s, not {expected} steps of {h:g} s to {stop:g} s "
                           "(export it again with 'wmr ssp export')")
        run = log_rows(package, variables, steps, h, False, str(oms.version),
                       after_transfer=True)
        run.extra["model_name"] = model_name(package)
        return run


def _signals_regex(names: dict[str, list[str]]) -> str:
    """A regular expression (C++ ``std::regex``, matched against the whole name) of the
    signals ``<system>.<component>.<variable>`` of ``names``."""
    alternatives = [f"{re.escape(c)}\\.{re.escape(n)}" for c, ns in names.items() for n in ns]
    return f".*\\.({'|'.join(alternatives)})"


#: Calls one of OMSimulator's C functions through its Python package's ``Capi`` by name;
#: raises :class:`FmuError` on an error status.
Call = Callable[..., None]


@contextmanager
def _imported(oms: Any, package: SspPackage, folder: Path, work: Path
              ) -> Iterator[tuple[str, Call]]:
    """The package imported by ``oms_importFile`` (deleted on exit): the model's name and the
    caller of OMSimulator's functions; its log in ``work/omsimulator.log``, its temporary
    files in ``work/tmp``, and what its C code prints on standard error."""
    archive = work / "package.ssp"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                member = p.relative_to(folder).as_posix()
                if member == SSD_NAME:
                    zf.writestr(member, _with_model_name(p.read_bytes(), package))
                else:
                    zf.write(p, member)
    capi = oms.Capi

    def call(name: str, *args: Any) -> None:
        status = getattr(capi, name)(*args)
        if getattr(status, "value", status) > _WARNING:
            raise FmuError(f"{package.path}: OMSimulator's oms_{name} failed"
                           f"{_logged_error(work)}")

    with c_stdout_to_stderr():
        call("setLogFile", str(work / "omsimulator.log"))
        try:
            call("setTempDirectory", str(work / "tmp"))
            # an FMI 3.0 package is an algebraic loop to OMSimulator at this version (it reads
            # no FMI 3.0 InitialUnknown: every initial output depends on every input, docs/
            # ssp.md); its default loop solver, KINSOL, needs directional derivatives, which
            # our FMUs do not provide.  No loop in an FMI 2.0 package: the option is inert
            call("setCommandLineOption", f"--algLoopSolver={ALG_LOOP_SOLVER}")
            # the Python package wraps no oms_importFile: the library's own SSP import
            lib = capi.obj
            lib.oms_importFile.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p)]
            lib.oms_importFile.restype = ctypes.c_int
            cref = ctypes.c_char_p()
            if lib.oms_importFile(str(archive).encode(), ctypes.byref(cref)) > _WARNING \
                    or not cref.value:
                raise FmuError(f"{package.path}: OMSimulator cannot import the package"
                               f"{_logged_error(work)}")
            model = cref.value.decode()
            try:
                yield model, call
            finally:
                capi.delete(model)
        finally:
            with _fd1_to_devnull():  # "Logging information has been saved to" a removed file
                capi.setLogFile("")


def model_name(package: SspPackage) -> str:
    """The name OMSimulator's model gets: the package's (its SSD's ``name``) if it is an
    identifier OMSimulator takes (``^[a-zA-Z][a-zA-Z0-9_]*$``, ``src/OMSimulatorLib/
    ComRef.cpp``), else that name with every other character made ``_`` (and ``p_`` before
    it if it does not begin with a letter): OMSimulator refuses a package named as a variant
    run (``fig11-to_5_5_30deg``) with ``[NewModel] "..." is not a valid ident``."""
    if _IDENT.fullmatch(package.name):
        return package.name
    name = re.sub(r"[^A-Za-z0-9_]", "_", package.name)
    return name if name[:1].isascii() and name[:1].isalpha() else f"p_{name}"


def _with_model_name(ssd: bytes, package: SspPackage) -> bytes:
    """The SSD with its ``name`` made :func:`model_name` (nothing else changes what runs)."""
    name = model_name(package)
    if name == package.name:
        return ssd
    root = parse_xml(ssd, f"{package.path}: {SSD_NAME}")
    root.set("name", name)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


@contextmanager
def _fd1_to_devnull() -> Iterator[None]:
    """Drop what C code prints on the process's standard output (fd 1) meanwhile."""
    libc = ctypes.CDLL(None)
    libc.fflush(None)
    saved, devnull = os.dup(1), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        libc.fflush(None)
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def _logged_error(work: Path) -> str:
    """``": <the last error OMSimulator logged>"``, or nothing (its functions return only a
    status)."""
    log = work / "omsimulator.log"
    if not log.is_file():
        return ""
    with log.open("rb") as f:
        f.seek(max(0, log.stat().st_size - _LOG_TAIL_BYTES))
        tail = f.read().decode("utf-8", "replace").splitlines()
    # lines "<date> | error:   [where] what"
    errors = [x.split("error:", 1)[1].strip() for x in tail if "error:" in x]
    return f": {errors[-1]}" if errors else ""


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


__all__ = ["ALG_LOOP_SOLVER", "MODULE", "converged_at_s", "model_name", "omsimulator",
           "omsimulator_version", "read_result", "simulate_omsimulator"]

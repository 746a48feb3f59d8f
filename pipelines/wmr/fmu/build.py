"""``wmr fmu build``: Modelica source -> pymoca -> explicit ODE -> CasADi C -> gcc -> .fmu.

One FMI 2.0 and one FMI 3.0 co-simulation FMU are built from the same generated model core and
the same FMI layer (``fmu/src``); only ``fmi2.c`` or ``fmi3.c`` and the model description differ.
A build is skipped when a digest over every input (Modelica sources, C sources, this build
code, the tool versions and the compiler flags) matches the digest of the FMUs already there.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import platform
import shutil
import subprocess
import tempfile
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from wmr import __version__, paths
from wmr.errors import BuildError

CFLAGS = ("-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-std=c99", "-Wall", "-Wextra")
FMI_VERSIONS = (2, 3)
#: Where each FMI version puts the Linux x86_64 binary.
_PLATFORM_DIR = {2: "linux64", 3: "x86_64-linux"}
_STAMP = ".wmr-build.json"
_ZIP_DATE = (2020, 1, 1, 0, 0, 0)  # fixed, so that identical inputs give identical archives


@dataclass(frozen=True)
class BuildResult:
    """The FMUs of one build and whether they were reused."""

    fmus: dict[int, Path]
    digest: str
    reused: bool
    #: The controller FMUs (:mod:`wmr.fmu.controller`) by FMI version.
    controllers: dict[int, Path] = field(default_factory=dict)


def fmu_name(fmi_version: int) -> str:
    return f"wmr_robot-fmi{fmi_version}.fmu"


def controller_fmu_name(fmi_version: int) -> str:
    return f"wmr_controller-fmi{fmi_version}.fmu"


def _products(out_dir: Path) -> dict[str, Path]:
    """Every FMU of a build by stamp key: the robot's ``"2"``, the controller's ``"c2"``."""
    fmus = {str(v): out_dir / fmu_name(v) for v in FMI_VERSIONS}
    fmus.update({f"c{v}": out_dir / controller_fmu_name(v) for v in FMI_VERSIONS})
    return fmus


def _compiler_version(cc: str) -> str:
    try:
        out = subprocess.run([cc, "--version"], capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError) as exc:
        raise BuildError(f"no C compiler: '{cc} --version' failed ({exc}); install gcc") from exc
    return out.stdout.splitlines()[0] if out.stdout else cc


def _fmi_headers() -> Path:
    import fmpy

    headers = Path(fmpy.__file__).parent / "c-code"
    if not (headers / "fmi2Functions.h").exists() or not (headers / "fmi3Functions.h").exists():
        raise BuildError(f"the FMI headers are missing from fmpy ({headers}); reinstall fmpy")
    return headers


def _hand_written_sources() -> list[Path]:
    src = paths.fmu_src_dir()
    files = sorted(p for p in src.iterdir() if p.suffix in {".c", ".h"})
    needed = {"model.h", "fmi_layer.c", "fmi_layer.h", "solver.c", "solver.h", "fmi2.c", "fmi3.c"}
    missing = needed - {p.name for p in files}
    if missing:
        raise BuildError(f"{src} lacks {', '.join(sorted(missing))}")
    return files


def build_digest(cc: str = "gcc") -> str:
    """SHA-256 over everything that goes into an FMU."""
    import casadi
    import pymoca

    from wmr.fmu.flatten import source_digest

    h = hashlib.sha256()
    h.update(source_digest(paths.modelica_dir()).encode())
    for path in _hand_written_sources():
        h.update(path.name.encode())
        h.update(path.read_bytes())
    for path in sorted((paths.fmu_src_dir() / "controller").iterdir()):
        h.update(f"controller/{path.name}".encode())
        h.update(path.read_bytes())
    for module in sorted(Path(__file__).parent.glob("*.py")):
        h.update(module.name.encode())
        h.update(module.read_bytes())
    h.update(" ".join([casadi.__version__, pymoca.__version__, __version__,
                       _compiler_version(cc), *CFLAGS]).encode())
    return h.hexdigest()


@contextmanager
def _locked(out_dir: Path) -> Iterator[None]:
    """Serialise builds into one folder (batch workers may all ask for the FMUs at once)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".wmr-build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _reusable(out_dir: Path, digest: str) -> dict[str, Path] | None:
    stamp = out_dir / _STAMP
    fmus = _products(out_dir)
    if not stamp.exists() or not all(p.exists() for p in fmus.values()):
        return None
    try:
        recorded = json.loads(stamp.read_text())
    except (OSError, ValueError):
        return None
    if recorded.get("digest") != digest:
        return None
    for key, p in fmus.items():
        if recorded.get("sha256", {}).get(key) != hashlib.sha256(p.read_bytes()).hexdigest():
            return None
    return fmus


def _compile(cc: str, sources: list[Path], include_dirs: list[Path], output: Path) -> None:
    cmd = [cc, *CFLAGS, *(f"-I{d}" for d in include_dirs), *map(str, sources),
           "-o", str(output), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"the C compiler failed:\n{' '.join(cmd)}\n{proc.stderr.strip()}")
    if proc.stderr.strip():
        raise BuildError(f"the C sources must compile without warnings:\n{proc.stderr.strip()}")


def _check_exports(library: Path) -> None:
    """Only the fmi* entry points may leave the shared library."""
    try:
        proc = subprocess.run(["nm", "-D", "--defined-only", str(library)],
                              capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return  # binutils missing: nothing to check with, the FMU is still valid
    names = [line.split()[-1] for line in proc.stdout.splitlines() if line.strip()]
    stray = [n for n in names if not n.startswith("fmi") and n[:1] != "_"]
    if stray:
        raise BuildError(f"{library.name} exports non-FMI symbols: {', '.join(stray)}")


def _write_zip(target: Path, members: dict[str, bytes]) -> None:
    """Write the archive next to ``target`` and move it into place atomically."""
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=".", suffix=".fmu.part")
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for name in sorted(members):
                info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                zf.writestr(info, members[name])
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def build_fmus(out_dir: str | os.PathLike[str] | None = None, *, force: bool = False,
               cc: str = "gcc", validate: bool = True) -> BuildResult:
    """Build (or reuse) the FMI 2.0 and FMI 3.0 co-simulation FMUs into ``out_dir``.

    Parameters
    ----------
    out_dir
        Folder for the two ``.fmu`` files; :func:`wmr.paths.default_fmu_dir` by default.
    force
        Rebuild even when the digest of the inputs matches the existing FMUs.
    cc
        The C compiler.
    validate
        Run fmpy's ``validate_fmu`` on each new FMU and fail on any problem.

    Raises
    ------
    BuildError
        With the failing step and what to do.
    """
    if platform.system() != "Linux" or platform.machine() not in {"x86_64", "AMD64"}:
        raise BuildError(
            f"binaries are built for Linux x86_64 only, this is {platform.system()} "
            f"{platform.machine()}: compile the FMU's sources/ folder with your C compiler")
    out = Path(out_dir) if out_dir is not None else paths.default_fmu_dir()
    digest = build_digest(cc)
    with _locked(out):
        if not force:
            reused = _reusable(out, digest)
            if reused is not None:
                return _result(reused, digest, reused=True)
        fmus = _build(out, digest, cc)
        controllers = _build(out, digest, cc, "controller")
        if validate:
            _validate(fmus)
            _validate(controllers)
        products = _products(out)
        stamp = {"digest": digest, "sha256": {
            key: hashlib.sha256(p.read_bytes()).hexdigest() for key, p in products.items()}}
        (out / _STAMP).write_text(json.dumps(stamp, indent=1) + "\n")
    return _result(products, digest, reused=False)


def _result(products: dict[str, Path], digest: str, reused: bool) -> BuildResult:
    return BuildResult({v: products[str(v)] for v in FMI_VERSIONS}, digest, reused,
                       controllers={v: products[f"c{v}"] for v in FMI_VERSIONS})


def _build(out: Path, digest: str, cc: str, product: str = "robot") -> dict[int, Path]:
    """Build one product, ``robot`` or ``controller``, for every FMI version."""
    from wmr.fmu.codegen import MODEL_IDENTIFIER, write_model_core
    from wmr.fmu.controller import ControllerModel
    from wmr.fmu.flatten import FlatModel
    from wmr.fmu.modeldesc import (
        fmi2_model_description,
        fmi3_build_description,
        fmi3_model_description,
        token_from_digest,
    )

    model: FlatModel | ControllerModel
    extra: list[Path] = []  # hand-written C of the product's model core
    if product == "robot":
        from wmr.fmu.flatten import flatten

        model = flatten(paths.modelica_dir())
        identifier, name = MODEL_IDENTIFIER, fmu_name
        token = token_from_digest(digest)
    else:
        from wmr.fmu.controller import controller_model, controller_sources

        model = controller_model()
        identifier, name, extra = model.model_identifier, controller_fmu_name, \
            controller_sources()
        # its own token: an importer must not pair the robot's description with this binary
        token = token_from_digest(hashlib.sha256(f"{identifier}:{digest}".encode()).hexdigest())
    headers = _fmi_headers()
    hand = _hand_written_sources() + extra
    result: dict[int, Path] = {}
    with tempfile.TemporaryDirectory(prefix="wmr-fmu-") as tmp:
        gen_dir = Path(tmp) / "generated"
        if isinstance(model, ControllerModel):
            from wmr.fmu.controller import write_controller_core

            generated = write_controller_core(model, token, gen_dir)
        else:
            generated = write_model_core(model, token, gen_dir)
        for version in FMI_VERSIONS:
            skip = "fmi3.c" if version == 2 else "fmi2.c"
            sources = [p for p in hand if p.name != skip] + generated
            c_files = [p for p in sources if p.suffix == ".c"]
            library = Path(tmp) / f"fmi{version}" / f"{identifier}.so"
            library.parent.mkdir()
            _compile(cc, c_files, [gen_dir, paths.fmu_src_dir(), headers], library)
            _check_exports(library)
            c_names = [p.name for p in c_files]
            members = {f"sources/{p.name}": p.read_bytes() for p in sources}
            members[f"binaries/{_PLATFORM_DIR[version]}/{identifier}.so"] = \
                library.read_bytes()
            if version == 2:
                members["modelDescription.xml"] = fmi2_model_description(model, token, c_names)
            else:
                members["modelDescription.xml"] = fmi3_model_description(model, token)
                members["sources/buildDescription.xml"] = fmi3_build_description(c_names,
                                                                                  identifier)
            readme = paths.fmu_src_dir() / "README.md"
            if readme.exists():
                members["documentation/README.md"] = readme.read_bytes()
            target = out / name(version)
            _write_zip(target, members)
            result[version] = target
    return result


def _validate(fmus: dict[int, Path]) -> None:
    from fmpy.validation import validate_fmu

    for version, path in fmus.items():
        problems = validate_fmu(str(path))
        if problems:
            raise BuildError(f"fmpy rejects the FMI {version} FMU {path}: " + "; ".join(problems))


def copy_fmus(result: BuildResult, dest: Path) -> dict[int, Path]:
    """Copy built FMUs into ``dest`` (e.g. next to a batch's logs)."""
    dest.mkdir(parents=True, exist_ok=True)
    return {v: Path(shutil.copy2(p, dest / p.name)) for v, p in result.fmus.items()}

"""``wmr fmu build``: Modelica source -> pymoca -> explicit ODE -> CasADi C -> zig/gcc -> .fmu.

One FMI 2.0 and one FMI 3.0 FMU are built from the same generated model core and the same FMI
layer (``fmu/src``); only ``fmi2.c`` or ``fmi3.c`` and the model description differ.  With Zig's
C compiler (the ``ziglang`` package) each FMU carries binaries for every platform the FMI
standard names (:mod:`wmr.build.platforms`); with the host's gcc, for the host only.  The
compiles run concurrently.  A build is skipped when a digest over every input (Modelica
sources, C sources, this build code, the tool and compiler versions, the flags and the target
platforms) matches the digest of the FMUs already there.

``platforms`` chooses the binaries: ``"all"`` (``wmr fmu build``, ``wmr ssp export``: the FMUs
to hand to other tools), ``"host"`` (the implicit build behind ``wmr run``, ``wmr batch`` and
the API: seconds with gcc, where Zig's first use on a machine builds its C libraries for five
platforms for minutes) or a list of FMI 3 platform names.  Each choice has its own cache folder,
so that a host build never replaces a full one.  A build reports each step through
``on_build``, and at least every :data:`PROGRESS_INTERVAL_S` while a compile or another
process's build runs.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
import time
import zipfile
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from wmr.build.platforms import (
    CFLAGS,
    GLIBC_FLOOR,
    PLATFORMS,
    Compiler,
    Platform,
    check_binary,
    find_compiler,
    parse_platforms,
)
from wmr.infra import paths
from wmr.infra.durable import open_own, storage_error
from wmr.infra.errors import BuildError, ConfigError, LogError
from wmr.infra.trust import make_folder, trust_root, untrusted
from wmr.infra.version import __version__

FMI_VERSIONS = (2, 3)
#: Longest silence of a build, s: a compile or a wait on another process's build says it is
#: still running at least this often.
PROGRESS_INTERVAL_S = 5.0
#: A progress line's receiver: one line of text, no newline.
Progress = Callable[[str], None]
_STAMP = ".wmr-build.json"
_ZIP_DATE = (2020, 1, 1, 0, 0, 0)  # fixed, so that identical inputs give identical archives


@dataclass(frozen=True)
class BuildResult:
    """The FMUs of one build and whether they were reused."""

    fmus: dict[int, Path]
    digest: str
    reused: bool
    #: FMI 3 names of the platforms the binaries were built for, in :data:`PLATFORMS` order.
    platforms: tuple[str, ...] = ()
    #: The controller FMUs (:mod:`wmr.build.controller_interface`) by FMI version.
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


def build_digest(compiler: Compiler | None = None,
                 platforms: Sequence[Platform] | None = None) -> str:
    """SHA-256 over everything that goes into an FMU."""
    compiler = compiler if compiler is not None else find_compiler()
    platforms = platforms if platforms is not None else compiler.platforms()
    import casadi
    import pymoca

    from wmr.build.flatten import source_digest

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
    h.update(" ".join([casadi.__version__, pymoca.__version__, __version__, compiler.version,
                       *CFLAGS]).encode())
    h.update(" ".join(f"{p.name}={p.zig_target if compiler.cross else 'host'}"
                      for p in platforms).encode())
    return h.hexdigest()


def _quiet(line: str) -> None:
    """The progress receiver of a build nobody watches."""


def _where(out_dir: Path) -> tuple[str, str]:
    """The field and the fix that a refusal of the folder ``out_dir`` names: the cache's
    ``WMR_CACHE_DIR`` for a folder in it, else ``out_dir``."""
    if trust_root(out_dir) != Path(os.path.abspath(out_dir)):
        return "WMR_CACHE_DIR", ("set WMR_CACHE_DIR to a folder only you can write, or build "
                                 "with 'wmr fmu build --out DIR'")
    return "out_dir", "give a folder only you can write"


@contextmanager
def _locked(out_dir: Path, progress: Progress = _quiet) -> Iterator[None]:
    """Serialise builds into one folder (batch workers may all ask for the FMUs at once); a
    process that waits on another's build says so, and how long, every
    :data:`PROGRESS_INTERVAL_S`.

    The folder is made 0700 in the cache (0755 elsewhere) whatever the umask, and refused when
    someone else could write it or a folder above it (:func:`wmr.infra.trust.untrusted`):
    libraries are loaded from it.
    """
    root = trust_root(out_dir)
    field_name, fix = _where(out_dir)
    try:
        make_folder(out_dir, root, 0o700 if root != Path(os.path.abspath(out_dir)) else 0o755)
    except OSError as exc:
        raise ConfigError(field_name, f"cannot create the FMU folder {out_dir} "
                          f"({exc.strerror or exc})", fix) from None
    reason = untrusted(out_dir, root)
    if reason is not None:
        raise ConfigError(field_name, f"{reason}: wmr loads libraries from the FMU folder "
                          f"{out_dir} and uses nothing there that others can change", fix)
    # never open(..., "w"): a link planted at the lock's name must not truncate its target
    try:
        lock = open_own(out_dir / ".wmr-build.lock", os.O_RDWR | os.O_CREAT, "build lock")
    except LogError as exc:
        raise ConfigError(field_name, str(exc), fix) from None
    try:
        t0 = time.monotonic()
        said = None
        while True:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                waited = time.monotonic() - t0
                if said is None or waited - said >= PROGRESS_INTERVAL_S:
                    progress(f"waiting for another process's build of the FMUs in {out_dir} "
                             f"({waited:.0f} s)")
                    said = waited
                time.sleep(min(0.2, PROGRESS_INTERVAL_S))
        if said is not None:
            progress(f"the other build finished after {time.monotonic() - t0:.0f} s")
        yield
    finally:
        os.close(lock)  # closing releases the lock


def _reusable(out_dir: Path, digest: str, progress: Progress = _quiet
              ) -> dict[str, Path] | None:
    """The FMUs in ``out_dir`` if its stamp records ``digest`` and their hashes, and each of
    them and the stamp may be trusted (:func:`wmr.infra.trust.untrusted`: a file others can
    have written is rebuilt, said in one ``progress`` line); else None."""
    stamp = out_dir / _STAMP
    fmus = _products(out_dir)
    if not stamp.exists() or not all(p.exists() for p in fmus.values()):
        return None
    root = trust_root(out_dir)
    for p in (stamp, *fmus.values()):
        reason = untrusted(p, root)
        if reason is not None:
            progress(f"{reason}: not reused, building the FMUs again")
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


def _compile(compiler: Compiler, target: Platform, sources: list[Path],
             include_dirs: list[Path], output: Path) -> None:
    """Compile one shared library; its own folder, since zig puts a ``.lib`` beside a DLL."""
    output.parent.mkdir(parents=True, exist_ok=True)
    cmd = compiler.argv(target, sources, include_dirs, output)
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=output.parent)
    if proc.returncode != 0:
        raise BuildError(f"the C compiler failed for {target.name}:\n{' '.join(cmd)}\n"
                         f"{proc.stderr.strip()}")
    if proc.stderr.strip():
        raise BuildError(f"the C sources must compile without warnings ({target.name}):\n"
                         f"{proc.stderr.strip()}")
    problems = check_binary(output, target, GLIBC_FLOOR if compiler.cross else None)
    if problems:
        raise BuildError("; ".join(problems))


def _write_zip(target: Path, members: dict[str, bytes]) -> None:
    """Write the archive next to ``target`` and move it into place atomically."""
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=".", suffix=".fmu.part")
    os.close(fd)
    try:
        os.chmod(tmp, 0o644)  # mkstemp's 0600 would keep the FMU from other users
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


def default_out_dir(platforms: str | Sequence[str] = "all") -> Path:
    """The cache folder of a build for ``platforms``: :func:`wmr.infra.paths.default_fmu_dir`
    for ``"all"``, a sibling ``fmu-<platform>[+<platform>...]`` for fewer (``fmu-x86_64-linux``
    for ``"host"`` on a Linux PC), so that a host build and a full build never replace each
    other."""
    chosen = parse_platforms(platforms)
    if chosen is None:
        return paths.default_fmu_dir()
    return paths.default_fmu_dir().with_name("fmu-" + "+".join(p.name for p in chosen))


def build_fmus(out_dir: str | os.PathLike[str] | None = None, *, force: bool = False,
               cc: str | None = None, validate: bool = True,
               platforms: str | Sequence[str] = "all",
               on_build: Progress | None = None) -> BuildResult:
    """Build (or reuse) the FMI 2.0 and FMI 3.0 FMUs into ``out_dir``.

    Parameters
    ----------
    out_dir
        Folder for the ``.fmu`` files; :func:`default_out_dir` of ``platforms`` by default.
    force
        Rebuild even when the digest of the inputs matches the existing FMUs.
    cc
        The C compiler: ``"zig"`` (any platform), a host compiler such as ``"gcc"`` (the host
        platform only), or None to choose: gcc for the host platform alone when it is on PATH,
        else zig when the ``ziglang`` package is installed, else gcc.
    validate
        Run fmpy's ``validate_fmu`` on each new FMU and fail on any problem.
    platforms
        ``"all"`` (every platform the compiler builds: five with zig, the host with gcc),
        ``"host"``, or FMI 3 platform names as a list or one comma-separated string
        (:func:`wmr.build.platforms.parse_platforms`).
    on_build
        Called with one line per step of a build (none when the FMUs are reused): what is built
        for which platforms with which compiler, each library compiled, the validation, and at
        least every :data:`PROGRESS_INTERVAL_S` while a compile, or another process's build of
        the same folder, is still running.

    Raises
    ------
    BuildError
        With the failing step and what to do.
    ConfigError
        For an unknown platform (field ``platforms``) or a folder that cannot be created
        (``out_dir``).
    """
    progress = on_build if on_build is not None else _quiet
    requested = parse_platforms(platforms)
    compiler = find_compiler(cc, requested)
    targets = compiler.targets(requested)
    out = Path(out_dir) if out_dir is not None else default_out_dir(platforms)
    digest = build_digest(compiler, targets)
    names = tuple(t.name for t in targets)
    with _locked(out, progress):
        if not force:
            reused = _reusable(out, digest, progress)
            if reused is not None:
                return _result(reused, digest, True, names)
        t0 = time.monotonic()
        slow = (" (Zig builds its C libraries for each platform on its first use on a "
                "machine: minutes)" if compiler.cross else "")
        progress(f"building the robot and controller FMUs for {', '.join(names)} with "
                 f"{compiler.version} into {out}{slow}")
        try:
            fmus = _build(out, digest, compiler, targets, progress=progress)
            controllers = _build(out, digest, compiler, targets, "controller",
                                 progress=progress)
            if validate:
                _validate(fmus, progress)
                _validate(controllers, progress)
            products = _products(out)
            stamp = {"digest": digest, "compiler": compiler.version, "platforms": list(names),
                     "sha256": {key: hashlib.sha256(p.read_bytes()).hexdigest()
                                for key, p in products.items()}}
            (out / _STAMP).write_text(json.dumps(stamp, indent=1) + "\n")
        except OSError as exc:  # a full disk names the file (or the folder) it hit
            raise storage_error(exc, exc.filename or out) from exc
        progress(f"built the FMUs in {time.monotonic() - t0:.0f} s")
    build_stepper(out, progress=progress)  # host-only, beside the FMUs (takes the lock)
    return _result(products, digest, False, names)


def _result(products: dict[str, Path], digest: str, reused: bool,
            platforms: tuple[str, ...]) -> BuildResult:
    return BuildResult({v: products[str(v)] for v in FMI_VERSIONS}, digest, reused,
                       platforms=platforms,
                       controllers={v: products[f"c{v}"] for v in FMI_VERSIONS})


def _compile_all(compiler: Compiler, jobs: list[tuple[int, Platform, Path, list[Path]]],
                 include: list[Path], product: str, progress: Progress) -> None:
    """Compile every job concurrently, with a line per library done and, while none finishes,
    a line every :data:`PROGRESS_INTERVAL_S` naming the ones still compiling."""
    t0 = time.monotonic()
    progress(f"{product}: compiling {len(jobs)} libraries (FMI "
             f"{' and '.join(str(v) for v in sorted({v for v, _, _, _ in jobs}))} x "
             f"{len({t for _, t, _, _ in jobs})} platforms)")
    workers = min(len(jobs), os.cpu_count() or 1)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        running: dict[Future[None], tuple[int, Platform]] = {
            pool.submit(_compile, compiler, t, sources, include, lib): (v, t)
            for v, t, lib, sources in jobs}
        done_count = 0
        try:
            while running:
                done, _ = wait(running, timeout=PROGRESS_INTERVAL_S,
                               return_when=FIRST_COMPLETED)
                elapsed = time.monotonic() - t0
                if not done:
                    # what runs now: the pool's first max_workers jobs not yet done
                    busy = list(running.values())[:workers]
                    progress(f"{product}: still compiling "
                             f"{', '.join(f'FMI {v} {t.name}' for v, t in busy)} "
                             f"({elapsed:.0f} s)")
                for future in done:
                    v, t = running.pop(future)
                    future.result()
                    done_count += 1
                    progress(f"{product}: compiled FMI {v} {t.name} "
                             f"({done_count}/{len(jobs)}, {elapsed:.0f} s)")
        except BaseException:
            for future in running:
                future.cancel()
            raise


def _build(out: Path, digest: str, compiler: Compiler, targets: Sequence[Platform],
           product: str = "robot", progress: Progress = _quiet) -> dict[int, Path]:
    """Build one product, ``robot`` or ``controller``, for every FMI version and platform."""
    from wmr.build.codegen import unity_source, write_model_core
    from wmr.build.controller_interface import ControllerModel
    from wmr.build.documentation import index_html, license_files
    from wmr.build.flatten import MODEL_IDENTIFIER, FlatModel
    from wmr.build.modeldesc import (
        fmi2_model_description,
        fmi3_build_description,
        fmi3_model_description,
        token_from_digest,
    )

    model: FlatModel | ControllerModel
    extra: list[Path] = []  # hand-written C of the product's model core
    progress(f"{product}: generating the C sources")
    if product == "robot":
        from wmr.build.flatten import flatten

        model = flatten(paths.modelica_dir())
        identifier, name = MODEL_IDENTIFIER, fmu_name
        token = token_from_digest(digest)
    else:
        from wmr.build.controller_interface import controller_model, controller_sources

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
            from wmr.build.controller_interface import write_controller_core

            generated = write_controller_core(model, token, gen_dir)
        else:
            generated = write_model_core(model, token, gen_dir)
        # One translation unit per FMI version includes all the others, so that only the fmi*
        # entry points are global symbols (fmu/src/README.md).
        unity: dict[int, Path] = {}
        for v in FMI_VERSIONS:
            unity[v] = Path(tmp) / f"fmi{v}" / f"{identifier}.c"
            unity[v].parent.mkdir()
            unity[v].write_text(unity_source(model, v))
        sources = {v: [p for p in hand if p.name != ("fmi3.c" if v == 2 else "fmi2.c")]
                   + generated + [unity[v]] for v in FMI_VERSIONS}
        # One job per FMI version and platform; FMI 2 has no folder name for aarch64.
        jobs = [(v, t, Path(tmp) / f"fmi{v}" / t.name / f"{identifier}{t.extension}",
                 [unity[v]]) for v in FMI_VERSIONS for t in targets if t.folder(v) is not None]
        include = [gen_dir, paths.fmu_src_dir(), headers,
                   *sorted({p.parent for p in extra})]
        _compile_all(compiler, jobs, include, product, progress)
        if isinstance(model, ControllerModel):
            from wmr.build.controller_interface import index_html as controller_index

            page = controller_index(model)
        else:
            page = index_html(model)
        docs = {"documentation/index.html": page.encode(), **license_files()}
        readme = paths.fmu_src_dir() / "README.md"
        if readme.exists():
            docs["documentation/README.md"] = readme.read_bytes()
        for version in FMI_VERSIONS:
            c_names = [unity[version].name]
            members = {f"sources/{p.name}": p.read_bytes() for p in sources[version]}
            members.update(docs)
            for v, t, lib, _ in jobs:
                if v == version:
                    members[f"binaries/{t.folder(v)}/{lib.name}"] = lib.read_bytes()
            if version == 2:
                members["modelDescription.xml"] = fmi2_model_description(model, token, c_names)
            else:
                members["modelDescription.xml"] = fmi3_model_description(model, token)
                members["sources/buildDescription.xml"] = fmi3_build_description(c_names,
                                                                                  identifier)
            target = out / name(version)
            _write_zip(target, members)
            result[version] = target
    return result


def _validate(fmus: dict[int, Path], progress: Progress = _quiet) -> None:
    from fmpy.validation import validate_fmu

    for version, path in fmus.items():
        progress(f"validating {path.name} with fmpy")
        problems = validate_fmu(str(path))
        if problems:
            raise BuildError(f"fmpy rejects the FMI {version} FMU {path}: " + "; ".join(problems))


@dataclass(frozen=True)
class FmuSummary:
    """What one FMU file offers, read back from the archive itself."""

    path: Path
    fmi_version: str
    interfaces: tuple[str, ...]  # "co-simulation", "model exchange", "scheduled execution"
    platforms: tuple[str, ...]  # folder names under binaries/, in PLATFORMS order

    def line(self, requested: Sequence[str] | None = None) -> str:
        """``<file name>: FMI 3.0, co-simulation, x86_64-linux aarch64-linux ...``; for FMI 2
        also which of the ``requested`` platforms (FMI 3 names; every platform by default) it
        leaves out, and why: FMI 2.0 has no standard platform name for aarch64, so those
        binaries are in the FMI 3.0 FMU only.  A host-only build asked for no aarch64 and is
        told of none."""
        text = (f"{self.path.name}: FMI {self.fmi_version}, {' + '.join(self.interfaces)}, "
                f"binaries for {' '.join(self.platforms) or 'no platform'}")
        if self.fmi_version.startswith("2"):
            missing = [p.name for p in PLATFORMS if p.fmi2 is None
                       and (requested is None or p.name in requested)]
            if missing:
                them = "it" if len(missing) == 1 else "them"
                text += (f" (no {', '.join(missing)} binaries: FMI 2.0 has no standard platform "
                         f"name for {them}; the FMI 3.0 FMU carries {them})")
        return text


def summarize(path: Path) -> FmuSummary:
    """Read the FMI version, interfaces and binary platforms of the FMU at ``path``."""
    from fmpy import read_model_description

    md = read_model_description(str(path))
    interfaces = tuple(name for name, present in (
        ("co-simulation", md.coSimulation), ("model exchange", md.modelExchange),
        ("scheduled execution", getattr(md, "scheduledExecution", None))) if present)
    with zipfile.ZipFile(path) as zf:
        folders = {n.split("/")[1] for n in zf.namelist()
                   if n.startswith("binaries/") and n.count("/") == 2 and not n.endswith("/")}
    order = [f for p in PLATFORMS for f in (p.name, p.fmi2) if f]
    platforms = tuple(sorted(folders, key=lambda f: order.index(f) if f in order else len(order)))
    return FmuSummary(path, md.fmiVersion, interfaces, platforms)


#: Flags of the stepper: ``-ffp-contract=off`` keeps every operation rounded on its own, as in
#: the Python code it must equal bit for bit.
STEPPER_CFLAGS = ("-O2", "-g0", "-fPIC", "-shared", "-std=c99", "-Wall", "-Wextra",
                  "-ffp-contract=off")


def stepper_source() -> Path:
    """The master loop's C stepper (``fmu/src/stepper/wmr_stepper.c``), in no FMU: one unity
    file that includes its parts (:func:`stepper_sources`)."""
    return paths.fmu_src_dir() / "stepper" / "wmr_stepper.c"


def stepper_sources() -> list[Path]:
    """Every file of the stepper (its unity file, the parts it includes and its header
    ``wmr_stepper.h``), in a fixed order: what the library's name is a digest of."""
    return sorted(p for p in stepper_source().parent.iterdir()
                  if p.suffix in {".c", ".h"} and p.is_file())


def build_stepper(out_dir: str | os.PathLike[str] | None = None,
                  cc: str | None = None, progress: Progress = _quiet,
                  compile_now: bool = True) -> Path | None:
    """Compile (or reuse) the C stepper for this host beside the FMUs; None without a compiler.

    The stepper holds the paper's law too (the controller FMU's core
    ``fmu/src/controller/controller.c`` with its generated index headers), so that a run of the
    Python stabiliser can run whole blocks of the closed loop in C with the same bits.

    The library is named by a digest of its sources, the generated headers, the flags and the
    compiler's version, so that a changed source is never served by an old binary.  The stepper
    is host-only (it is loaded by this Python, never shipped): without a host C compiler, or
    when the compile fails, the master loop runs its pure-Python path, which gives the same
    bits.

    A library there is returned only if it may be trusted (:func:`wmr.infra.trust.untrusted`:
    no one else can have written it or a folder above it); one others could have written is
    compiled again over it, said in one ``progress`` line.

    Parameters
    ----------
    out_dir
        Folder of the FMUs; :func:`wmr.infra.paths.default_fmu_dir` by default.
    cc
        Host C compiler; the ``CC`` environment variable, else ``cc``, else ``gcc``.
    progress
        Receives the line saying why an existing library is not used.
    compile_now
        Compile it when it is not there (default); False: only a library built before, or
        None (what a run asks in its middle: a build is for before the run).

    Raises
    ------
    ConfigError
        The folder, or one above it, can be written by someone else (or cannot be made).
    """
    from wmr.build.codegen import sizes_header
    from wmr.build.controller_interface import (
        controller_model,
        controller_sources,
        indices_header,
    )

    cc = cc or os.environ.get("CC") or next((c for c in ("cc", "gcc") if shutil.which(c)), None)
    if cc is None or shutil.which(cc) is None:
        return None
    src = stepper_source()
    try:
        headers = _fmi_headers()
        law_sources = [paths.fmu_src_dir() / "model.h", *controller_sources()]
        version = subprocess.run([cc, "--version"], capture_output=True, text=True,
                                 check=True).stdout.splitlines()[0]
    except (BuildError, OSError, subprocess.CalledProcessError, IndexError):
        return None
    model = controller_model()
    generated = {"model_sizes.h": sizes_header(model), "model_indices.h": indices_header(model)}
    h = hashlib.sha256()
    for f in [*stepper_sources(), *law_sources]:
        h.update(f.read_bytes())
    for text in generated.values():
        h.update(text.encode())
    h.update(" ".join([version, *STEPPER_CFLAGS]).encode())
    out = Path(out_dir) if out_dir is not None else paths.default_fmu_dir()
    lib = out / f"wmr_stepper-{h.hexdigest()[:16]}.so"
    if lib.exists() and untrusted(lib, trust_root(out)) is None:
        return lib
    if not compile_now:
        return None
    with _locked(out), tempfile.TemporaryDirectory(dir=out, prefix=".stepper-") as gen:
        if lib.exists():
            reason = untrusted(lib, trust_root(out))
            if reason is None:  # another process built it meanwhile
                return lib
            progress(f"{reason}: not loaded, compiling the C stepper again")
        for name, text in generated.items():
            Path(gen, name).write_text(text)
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".", suffix=".so.part")
        os.close(fd)
        try:
            includes = [f"-I{gen}", f"-I{paths.fmu_src_dir()}",
                        f"-I{law_sources[1].parent}", f"-I{headers}"]
            proc = subprocess.run([cc, *STEPPER_CFLAGS, *includes,
                                   str(src), "-o", tmp, "-lm"], capture_output=True, text=True)
            if proc.returncode != 0 or proc.stderr.strip():
                return None
            os.chmod(tmp, 0o755)
            os.replace(tmp, lib)
        finally:
            Path(tmp).unlink(missing_ok=True)
    return lib


def copy_fmus(result: BuildResult, dest: Path) -> dict[int, Path]:
    """Copy built FMUs into ``dest`` (e.g. next to a batch's logs)."""
    dest.mkdir(parents=True, exist_ok=True)
    return {v: Path(shutil.copy2(p, dest / p.name)) for v, p in result.fmus.items()}

"""The binary platforms of the FMUs, the C compilers that target them, and the binary checks.

Zig's C compiler (the ``ziglang`` PyPI package) cross-compiles the FMU sources for every
platform the FMI standard names from any host: it ships the libc headers and link stubs of each
target, so the Linux binaries link against glibc 2.17 symbols (they load on RHEL/CentOS 7 and
newer) and the Windows DLL against the Universal CRT.  Without zig, the host's ``gcc`` builds the
host platform only.  Every binary is checked with LIEF (one parser for ELF, PE and Mach-O): its
format and architecture, that it exports only the ``fmi*`` entry points, and for Linux that no
symbol it imports needs a glibc newer than 2.17.
"""

from __future__ import annotations

import platform as _host
import re
import shutil
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from wmr.infra.errors import BuildError, ConfigError

#: The oldest glibc the Linux binaries may need (RHEL/CentOS 7).
GLIBC_FLOOR = (2, 17)
#: The oldest macOS the darwin binaries load on (11.0, Big Sur: the first with arm64).
MACOS_MIN = "11.0"
#: Flags for every compiler and platform.  ``-g0`` and no absolute paths in the objects keep the
#: binaries byte-identical between builds; ``-fvisibility=hidden`` leaves only what the FMI
#: headers mark ``FMI2_Export``/``FMI3_Export`` visible.  (CasADi's ``CASADI_SYMBOL_EXPORT``,
#: ``__declspec(dllexport)`` on Windows, is made ``static`` by the generated model core itself:
#: see :func:`wmr.build.codegen.model_source`.)
CFLAGS = ("-O2", "-g0", "-fvisibility=hidden", "-std=c99", "-Wall", "-Wextra")


@dataclass(frozen=True)
class Platform:
    """One binary platform of the FMUs.

    Attributes
    ----------
    name
        The FMI 3.0 platform tuple (``binaries/<name>/`` in an FMI 3 FMU).
    fmi2
        The FMI 2.0 folder name, or None where FMI 2.0 names no such platform (aarch64).
    zig_target
        The target of ``zig cc -target``.
    extension
        The shared library's file extension.
    binary_format, machine
        What LIEF must find in the binary: ``ELF``, ``PE`` or ``MachO`` and the architecture.
    """

    name: str
    fmi2: str | None
    zig_target: str
    extension: str
    binary_format: str
    machine: str

    def folder(self, fmi_version: int) -> str | None:
        """The folder under ``binaries/`` for ``fmi_version``; None if that version has none."""
        return self.name if fmi_version >= 3 else self.fmi2


PLATFORMS = (
    Platform("x86_64-linux", "linux64", "x86_64-linux-gnu.2.17", ".so", "ELF", "x86_64"),
    Platform("aarch64-linux", None, "aarch64-linux-gnu.2.17", ".so", "ELF", "aarch64"),
    Platform("x86_64-windows", "win64", "x86_64-windows-gnu", ".dll", "PE", "x86_64"),
    Platform("x86_64-darwin", "darwin64", f"x86_64-macos.{MACOS_MIN}", ".dylib", "MachO",
             "x86_64"),
    Platform("aarch64-darwin", None, f"aarch64-macos.{MACOS_MIN}", ".dylib", "MachO",
             "aarch64"),
)
PLATFORM_BY_NAME = {p.name: p for p in PLATFORMS}


def host_platform() -> Platform | None:
    """The platform this Python runs on, if the FMUs have one for it."""
    machine = {"amd64": "x86_64", "arm64": "aarch64"}.get(_host.machine().lower(),
                                                          _host.machine().lower())
    system = {"Linux": "linux", "Windows": "windows", "Darwin": "darwin"}.get(_host.system())
    return PLATFORM_BY_NAME.get(f"{machine}-{system}")


@dataclass(frozen=True)
class Compiler:
    """A C compiler and the platforms it builds.

    Attributes
    ----------
    command
        The argv prefix that runs it: ``python -m ziglang cc`` or ``gcc``.
    version
        Its version line (part of the build digest).
    cross
        True for zig, which targets every platform; False for a host compiler.
    """

    command: tuple[str, ...]
    version: str
    cross: bool

    def platforms(self) -> tuple[Platform, ...]:
        """Every platform this compiler builds: all of :data:`PLATFORMS` for zig, the host's
        for a host compiler."""
        if self.cross:
            return PLATFORMS
        host = host_platform()
        if host is None or host.binary_format != "ELF":
            raise BuildError(
                f"without zig the FMUs can be built on Linux only, this is {_host.system()} "
                f"{_host.machine()}: pip install ziglang, or compile the FMU's sources/ folder "
                "with your C compiler")
        return (host,)

    def targets(self, requested: Sequence[Platform] | None) -> tuple[Platform, ...]:
        """The platforms to build of ``requested`` (None: every platform it can build).

        Raises
        ------
        BuildError
            When a host compiler is asked for another platform than the host's.
        """
        own = self.platforms()
        if requested is None:
            return own
        other = [p.name for p in requested if p not in own]
        if other:
            raise BuildError(f"{self.command[0]} builds {', '.join(p.name for p in own)} only, "
                             f"not {', '.join(other)}: pip install ziglang (every platform)")
        return tuple(requested)

    def argv(self, target: Platform, sources: list[Path], include_dirs: list[Path],
             output: Path) -> list[str]:
        """The command line that compiles ``sources`` into the shared library ``output``."""
        if self.cross:
            flags = ["-target", target.zig_target, "-shared", "-s"]
        else:
            flags = ["-shared"]
        if target.binary_format != "PE":
            flags.append("-fPIC")  # zig warns that -fPIC is unused on Windows
        if target.binary_format == "MachO":
            # The install name would otherwise be the absolute path of the temporary output,
            # different in every build.
            flags.append(f"-Wl,-install_name,@rpath/{output.name}")
        libm = ["-lm"] if target.binary_format == "ELF" else []
        return [*self.command, *flags, *CFLAGS, *(f"-I{d}" for d in include_dirs),
                *map(str, sources), "-o", str(output), *libm]


def _version_line(argv: list[str]) -> str:
    try:
        out = subprocess.run(argv, capture_output=True, text=True, check=True, timeout=60)
    except (OSError, subprocess.CalledProcessError, subprocess.TimeoutExpired) as exc:
        raise BuildError(f"no C compiler: '{' '.join(argv)}' failed ({exc}); "
                         "pip install ziglang, or install gcc") from exc
    return out.stdout.strip().splitlines()[0] if out.stdout.strip() else argv[0]


def zig_compiler() -> Compiler | None:
    """Zig's C compiler from the ``ziglang`` package, or None when it is not installed."""
    try:
        import ziglang  # noqa: F401
    except ImportError:
        return None
    command = (sys.executable, "-m", "ziglang")
    return Compiler((*command, "cc"), "zig " + _version_line([*command, "version"]), cross=True)


def parse_platforms(choice: str | Sequence[str]) -> tuple[Platform, ...] | None:
    """The platforms of a ``--platforms`` choice: None for ``"all"`` (every platform the
    compiler builds), the host's for ``"host"``, else the FMI 3 names given as a sequence or as
    one comma-separated string (``"x86_64-linux,x86_64-windows"``), in :data:`PLATFORMS`
    order.

    Raises
    ------
    ConfigError
        For an unknown name, an empty list, or ``"host"`` on a platform the FMUs do not have.
    """
    names = [n.strip() for n in (choice.split(",") if isinstance(choice, str) else choice)]
    names = [n for n in names if n]
    fix = f"give host, all or a comma-separated list of {', '.join(PLATFORM_BY_NAME)}"
    if not names:
        raise ConfigError("platforms", "is empty", fix)
    if names == ["all"]:
        return None
    chosen: set[Platform] = set()
    for name in names:
        if name == "host":
            host = host_platform()
            if host is None:
                raise ConfigError("platforms", f"this host ({_host.system()} "
                                  f"{_host.machine()}) is none of the FMUs' platforms", fix)
            chosen.add(host)
        elif name in PLATFORM_BY_NAME:
            chosen.add(PLATFORM_BY_NAME[name])
        else:
            raise ConfigError("platforms", f"unknown platform {name!r}", fix)
    return tuple(p for p in PLATFORMS if p in chosen)


def find_compiler(cc: str | None = None,
                  platforms: Sequence[Platform] | None = None) -> Compiler:
    """The compiler for a build: ``cc`` if given (``"zig"`` or a host compiler such as
    ``"gcc"``); else, for the host platform alone, the host's gcc when it is on PATH (seconds,
    where zig first builds its C libraries for the target, which takes minutes); else zig when
    installed, else the host's gcc.

    Raises
    ------
    BuildError
        When the compiler asked for (or any, with ``cc=None``) is not there.
    """
    host = host_platform()
    if (cc is None and platforms is not None and host is not None and host.binary_format == "ELF"
            and tuple(platforms) == (host,) and shutil.which("gcc") is not None):
        cc = "gcc"
    if cc in (None, "zig"):
        zig = zig_compiler()
        if zig is not None:
            return zig
        if cc == "zig":
            raise BuildError("cc='zig' but the ziglang package is missing: pip install ziglang")
        cc = "gcc"
    assert cc is not None
    if shutil.which(cc) is None:
        raise BuildError(f"no C compiler: '{cc}' is not on PATH; pip install ziglang (every "
                         "platform) or install gcc (this platform only)")
    return Compiler((cc,), _version_line([cc, "--version"]), cross=False)


def _fmi_export(name: str) -> bool:
    return name.startswith("fmi")


_LIEF_MACHINE = {"x86_64": ("X86_64", "AMD64"), "aarch64": ("AARCH64", "ARM64")}


def check_binary(path: Path, target: Platform,
                 glibc_floor: tuple[int, ...] | None = GLIBC_FLOOR) -> list[str]:
    """Problems of the shared library ``path`` built for ``target`` (empty when none).

    Checks the format and architecture, that every exported symbol is an ``fmi*`` entry
    point, and for ELF that no imported symbol needs a glibc newer than ``glibc_floor`` (None:
    not checked, for a host gcc build, which links against the host's glibc).
    """
    import lief

    lief.logging.disable()  # LIEF logs harmless parse notes to stderr
    binary = lief.parse(str(path))
    if binary is None:
        return [f"{path.name}: not a shared library LIEF can read"]
    problems: list[str] = []
    fmt = type(binary).__module__.rsplit(".", 1)[-1]  # lief.ELF / lief.PE / lief.MachO
    if fmt != target.binary_format:
        return [f"{path.name}: {fmt} binary where {target.binary_format} was expected"]
    exports: list[str]
    if isinstance(binary, lief.ELF.Binary):
        machine = binary.header.machine_type.name
        exports = [str(s.name) for s in binary.dynamic_symbols
                   if s.shndx != 0 and s.binding != lief.ELF.Symbol.BINDING.LOCAL
                   and s.name and s.type != lief.ELF.Symbol.TYPE.SECTION]
        needed = [v for v in (_glibc_version(s) for s in binary.dynamic_symbols) if v]
        if glibc_floor is not None and needed and max(needed) > glibc_floor:
            newest = ".".join(map(str, max(needed)))
            problems.append(f"{path.name}: needs GLIBC_{newest}, newer than the floor "
                            f"GLIBC_{'.'.join(map(str, glibc_floor))}")
    elif isinstance(binary, lief.PE.Binary):
        machine = binary.header.machine.name
        export = binary.get_export()
        exports = [str(e.name) for e in export.entries] if export is not None else []
    elif isinstance(binary, lief.MachO.Binary):
        machine = binary.header.cpu_type.name
        if binary.header.file_type != lief.MachO.Header.FILE_TYPE.DYLIB:
            problems.append(f"{path.name}: Mach-O {binary.header.file_type.name}, not a DYLIB")
        # Mach-O C symbols carry a leading underscore.
        exports = [name[1:] if name.startswith("_") else name
                   for name in (str(s.name) for s in binary.exported_symbols)]
    else:
        return [f"{path.name}: {fmt} binary where {target.binary_format} was expected"]
    if machine not in _LIEF_MACHINE[target.machine]:
        problems.append(f"{path.name}: architecture {machine}, expected {target.machine}")
    # Names with a leading underscore belong to the C implementation and the linker (zig's
    # Mach-O linker exports __mh_dylib_header and ___dso_handle from every dylib).
    stray = sorted(n for n in exports if not _fmi_export(n) and not n.startswith("_"))
    if stray:
        shown = ", ".join(stray[:8]) + (f" and {len(stray) - 8} more" if len(stray) > 8 else "")
        problems.append(f"{path.name} ({target.name}) exports {len(stray)} non-FMI symbols: "
                        f"{shown}")
    if not any(_fmi_export(n) for n in exports):
        problems.append(f"{path.name} ({target.name}) exports no fmi* entry point")
    return problems


_GLIBC = re.compile(r"GLIBC_(\d+(?:\.\d+)+)")


def _glibc_version(symbol: object) -> tuple[int, ...] | None:
    version = getattr(symbol, "symbol_version", None)
    if version is None or not version.has_auxiliary_version:
        return None
    match = _GLIBC.fullmatch(str(version.symbol_version_auxiliary.name))
    return tuple(int(part) for part in match[1].split(".")) if match else None

"""The FMUs' binaries for every FMI platform: what is in them, what they export, and that the
foreign ones compute what linux64 computes (aarch64 under qemu-aarch64, win64 under wine)."""

from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from wmr.build.fmus import BuildResult, build_digest, build_fmus, summarize
from wmr.build.platforms import (
    CFLAGS,
    PLATFORM_BY_NAME,
    PLATFORMS,
    Compiler,
    check_binary,
    find_compiler,
    host_platform,
    zig_compiler,
)
from wmr.infra.errors import BuildError

ALL = tuple(p.name for p in PLATFORMS)
HARNESS = Path(__file__).parent / "data" / "fmu_harness.c"
AARCH64_SYSROOT = Path("/usr/aarch64-linux-gnu")  # Debian's libc6-arm64-cross
N_STEPS, STEP_S = 100, 0.05


def _zig() -> Compiler:
    zig = zig_compiler()
    if zig is None:
        pytest.skip("the ziglang package is not installed: only the host platform is built")
    return zig


def _extract(fmu: Path, dest: Path) -> Path:
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(dest)
    return dest


@pytest.fixture(scope="module")
def unpacked(built: BuildResult, tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    root = tmp_path_factory.mktemp("unpacked")
    return {v: _extract(p, root / f"fmi{v}") for v, p in built.fmus.items()}


def test_every_fmu_carries_every_platform_fmi_names(built: BuildResult) -> None:
    _zig()
    assert built.platforms == ALL
    assert summarize(built.fmus[3]).platforms == ALL
    # FMI 2.0 names linux64, win64 and darwin64 only: no aarch64 binary can be in it.
    assert summarize(built.fmus[2]).platforms == ("linux64", "win64", "darwin64")
    assert "aarch64-linux, aarch64-darwin" in summarize(built.fmus[2]).line()


def test_fmus_are_readable_by_everyone_and_carry_documentation(built: BuildResult) -> None:
    for path in built.fmus.values():
        assert path.stat().st_mode & 0o777 == 0o644
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            html = zf.read("documentation/index.html").decode()
            licence = zf.read("documentation/licenses/LICENSE.txt").decode()
        assert "BSD 2-Clause License" in licence
        for needle in ("eq. 22", "Bunjaku", "Errata", "<code>tau_r</code></td><td>N.m",
                       "<code>omega_r</code></td><td>rad/s", "<code>Iwm</code></td><td>kg.m2"):
            assert needle.replace("eq. 22", "<td>22</td>") in html, needle
        assert {"documentation/index.html", "modelDescription.xml"} <= names


def test_errata_in_the_fmu_documentation_match_docs_model_md() -> None:
    from wmr.build.documentation import ERRATA

    text = (Path(__file__).parents[1] / "docs" / "model.md").read_text()
    table = text.split("## Corrections", 1)[1].split("\n\n", 2)[1]
    rows = [[c.strip().replace("`", "") for c in line.strip("|").split(" | ")]
            for line in table.splitlines()[2:]]
    assert [tuple(r[:3]) for r in rows] == list(ERRATA)


@pytest.mark.parametrize("version", [2, 3])
def test_every_binary_passes_the_build_checks(unpacked: dict[int, Path], version: int) -> None:
    binaries = sorted((unpacked[version] / "binaries").glob("*/*"))
    assert binaries
    for path in binaries:
        folder = path.parent.name
        target = next(p for p in PLATFORMS if folder in (p.name, p.fmi2))
        assert check_binary(path, target) == [], path


def _elf_dynamic(path: Path) -> tuple[list[str], set[str]]:
    """objdump -T: (exported names, glibc versions the imports need)."""
    out = subprocess.run(["objdump", "-T", str(path)], capture_output=True, text=True,
                         check=True).stdout
    exports, versions = [], set()
    for line in out.splitlines():
        fields = line.split()
        match = re.search(r"\(?(GLIBC_[0-9.]+)\)?", line)
        if match:
            versions.add(match[1])
        if len(fields) >= 6 and "*UND*" not in line and fields[-1][:1].isalpha():
            exports.append(fields[-1])
    return exports, versions


@pytest.mark.skipif(shutil.which("objdump") is None, reason="binutils' objdump is not installed")
@pytest.mark.parametrize("folder", ["x86_64-linux", "aarch64-linux"])
def test_objdump_finds_glibc_217_at_most_and_only_fmi_exports(unpacked: dict[int, Path],
                                                              folder: str) -> None:
    """The check of the issue, with binutils instead of LIEF."""
    _zig()
    exports, versions = _elf_dynamic(unpacked[3] / "binaries" / folder / "wmr_robot.so")
    assert versions and all(tuple(map(int, v[6:].split("."))) <= (2, 17) for v in versions)
    assert exports and all(n.startswith("fmi3") for n in exports), exports


def _pe_exports(path: Path) -> list[str]:
    out = subprocess.run(["objdump", "-p", str(path)], capture_output=True, text=True,
                         check=True).stdout
    table = out.split("[Ordinal/Name Pointer] Table", 1)[1].split("\n\n", 1)[0]
    return [line.split()[-1] for line in table.splitlines() if line.strip()]


@pytest.mark.skipif(shutil.which("objdump") is None, reason="binutils' objdump is not installed")
@pytest.mark.parametrize("version", [2, 3])
def test_win64_dll_exports_only_fmi(unpacked: dict[int, Path], version: int) -> None:
    _zig()
    folder = "win64" if version == 2 else "x86_64-windows"
    exports = _pe_exports(unpacked[version] / "binaries" / folder / "wmr_robot.dll")
    assert exports and all(n.startswith(f"fmi{version}") for n in exports), exports


_MACHO_CPU = {"x86_64": 0x01000007, "aarch64": 0x0100000C}


@pytest.mark.parametrize("version", [2, 3])
def test_darwin_binaries_are_mach_o_dylibs_of_their_architecture(unpacked: dict[int, Path],
                                                                 version: int) -> None:
    """Read from the Mach-O header itself, independently of LIEF: 64-bit magic, CPU type and
    MH_DYLIB (6); the exports are LIEF's (test_every_binary_passes_the_build_checks)."""
    _zig()
    folders = {"x86_64": "darwin64" if version == 2 else "x86_64-darwin"}
    if version == 3:
        folders["aarch64"] = "aarch64-darwin"
    for machine, folder in folders.items():
        head = (unpacked[version] / "binaries" / folder / "wmr_robot.dylib").read_bytes()[:16]
        magic, cpu, _, filetype = struct.unpack("<IiiI", head)
        assert (magic, cpu, filetype) == (0xFEEDFACF, _MACHO_CPU[machine], 6), folder


def _compile_lib(zig: Compiler, target: str, code: str, tmp: Path, name: str) -> Path:
    src = tmp / f"{name}.c"
    src.write_text(code)
    platform = PLATFORM_BY_NAME[target]
    out = tmp / f"{name}{platform.extension}"
    subprocess.run(zig.argv(platform, [src], [], out), check=True, capture_output=True,
                   cwd=tmp)
    return out


def test_the_checks_catch_a_stray_export_a_wrong_architecture_and_a_new_glibc(
        tmp_path: Path) -> None:
    zig = _zig()
    stray = _compile_lib(zig, "x86_64-linux",
                         '__attribute__((visibility("default"))) int fmi2Ok(void) {return 0;}\n'
                         '__attribute__((visibility("default"))) int helper(void) {return 1;}\n',
                         tmp_path, "stray")
    assert any("exports 1 non-FMI symbols: helper" in p
               for p in check_binary(stray, PLATFORM_BY_NAME["x86_64-linux"]))
    assert any("architecture X86_64, expected aarch64" in p
               for p in check_binary(stray, PLATFORM_BY_NAME["aarch64-linux"]))
    assert any("ELF binary where PE" in p
               for p in check_binary(stray, PLATFORM_BY_NAME["x86_64-windows"]))
    # pow needs GLIBC_2.29 when linked against a new glibc: what the issue found in linux64.
    src = tmp_path / "newglibc.c"
    src.write_text('#include <math.h>\n__attribute__((visibility("default"))) double '
                   'fmi2Pow(double a, double b) {return pow(a, b);}\n')
    new = tmp_path / "newglibc.so"
    subprocess.run([*zig.command, "-target", "x86_64-linux-gnu.2.34", "-shared", "-fPIC",
                    *CFLAGS, str(src), "-o", str(new), "-lm"], check=True, capture_output=True)
    assert any("needs GLIBC_2.29" in p for p in check_binary(new, PLATFORM_BY_NAME["x86_64-linux"]))


def test_the_digest_covers_the_compiler_and_the_platforms() -> None:
    zig = _zig()
    if shutil.which("gcc") is None:
        pytest.skip("gcc is not installed")
    everything = build_digest(zig, PLATFORMS)
    assert everything == build_digest(zig, PLATFORMS)
    assert everything != build_digest(zig, PLATFORMS[:1])
    assert build_digest(find_compiler("gcc"), PLATFORMS[:1]) != build_digest(zig, PLATFORMS[:1])


def test_without_zig_gcc_builds_the_host_platform(built: BuildResult, tmp_path: Path) -> None:
    host = host_platform()
    if shutil.which("gcc") is None or host is None or host.binary_format != "ELF":
        pytest.skip("needs gcc on Linux")
    with pytest.raises(BuildError, match="not on PATH"):
        find_compiler("no-such-cc-wmr")
    notices: list[str] = []
    gcc = build_fmus(tmp_path, cc="gcc", on_build=notices.append)  # validated by fmpy inside
    assert gcc.platforms == (host.name,) and gcc.digest != built.digest
    # a build says so before it starts (it may take minutes), then each step; a reuse says
    # nothing
    assert host.name in notices[0] and str(tmp_path) in notices[0]
    assert notices[0].startswith("building") and len(notices) > 1
    said = len(notices)
    assert build_fmus(tmp_path, cc="gcc", on_build=notices.append).reused
    assert len(notices) == said
    assert summarize(gcc.fmus[2]).platforms == (host.fmi2,)
    assert summarize(gcc.fmus[3]).platforms == (host.name,)


@pytest.mark.slow
def test_a_forced_rebuild_elsewhere_gives_the_same_bytes(built: BuildResult,
                                                         tmp_path: Path) -> None:
    """Reproducible: other folders, other temporary paths, the same archives."""
    again = build_fmus(tmp_path, force=True, validate=False)
    assert again.digest == built.digest
    for version, path in built.fmus.items():
        assert again.fmus[version].read_bytes() == path.read_bytes(), version


@pytest.mark.slow  # a Zig cross-compile of the whole model: minutes on 2 cores
def test_the_fmu_sources_alone_compile_to_a_dll_exporting_only_fmi(unpacked: dict[int, Path],
                                                                   tmp_path: Path) -> None:
    """What a Windows user gets who compiles the FMU's declared sources with no flag of ours
    but the include paths (the issue found 51 CasADi helpers exported)."""
    import xml.etree.ElementTree as ET

    import fmpy

    zig = _zig()
    src = unpacked[2] / "sources"
    names = list(dict.fromkeys(  # ME and CS list the same files
        f.get("name") for f in ET.parse(unpacked[2] / "modelDescription.xml").iter("File")))
    headers = Path(fmpy.__file__).parent / "c-code"
    windows = PLATFORM_BY_NAME["x86_64-windows"]
    out = tmp_path / "alone.dll"
    subprocess.run([*zig.command, "-target", windows.zig_target, "-shared", "-O2", f"-I{src}",
                    f"-I{headers}", *(str(src / str(n)) for n in names), "-o", str(out)],
                   check=True, capture_output=True, cwd=tmp_path)
    assert check_binary(out, windows) == []


# --- the foreign binaries run -------------------------------------------------------------

def _harness(zig: Compiler, target: str, out: Path) -> Path:
    import fmpy

    headers = Path(fmpy.__file__).parent / "c-code"
    platform = PLATFORM_BY_NAME[target]
    exe = out / f"harness-{target}{'.exe' if platform.binary_format == 'PE' else ''}"
    if not exe.exists():
        libs = [] if platform.binary_format == "PE" else ["-ldl"]
        subprocess.run([*zig.command, "-target", platform.zig_target, *CFLAGS, f"-I{headers}",
                        str(HARNESS), "-o", str(exe), *libs], check=True, capture_output=True,
                       cwd=out)
    return exe


def _arguments(fmu: Path) -> list[str]:
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [str(v.valueReference) for v in md.modelVariables if v.causality == "output"]
    return [str(fmu.name[-5]), md.guid, str(N_STEPS), repr(STEP_S), str(vr["tau_r"]),
            str(vr["tau_l"]), *outputs]


def _run(argv: list[str], env: dict[str, str] | None = None) -> np.ndarray:
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr
    rows = np.array([[float(x) for x in line.split()] for line in proc.stdout.splitlines()])
    assert rows.shape[0] == N_STEPS and np.isfinite(rows).all()
    return rows


@pytest.fixture(scope="module")
def harness_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("harness")


@pytest.fixture(scope="module")
def linux64(built: BuildResult, unpacked: dict[int, Path],
            harness_dir: Path) -> dict[int, np.ndarray]:
    """The reference: each FMU's x86_64-linux binary driven by the same harness."""
    zig = _zig()
    exe = _harness(zig, "x86_64-linux", harness_dir)
    folder = {2: "linux64", 3: "x86_64-linux"}
    return {v: _run([str(exe), str(unpacked[v] / "binaries" / folder[v] / "wmr_robot.so"),
                     *_arguments(built.fmus[v])]) for v in (2, 3)}


def _agree(foreign: np.ndarray, reference: np.ndarray) -> float:
    """Largest difference relative to max(1, |reference|), over every output and step."""
    return float(np.max(np.abs(foreign - reference) / np.maximum(1.0, np.abs(reference))))


def test_the_linux64_harness_run_moves_the_robot(linux64: dict[int, np.ndarray]) -> None:
    """Guards the comparisons below against a harness whose inputs do nothing."""
    assert np.ptp(linux64[3][:, 1:], axis=0).min() > 1e-3
    assert _agree(linux64[2], linux64[3]) < 1e-12


def test_aarch64_binary_under_qemu_gives_the_linux64_result(
        built: BuildResult, unpacked: dict[int, Path], harness_dir: Path,
        linux64: dict[int, np.ndarray]) -> None:
    if shutil.which("qemu-aarch64") is None:
        pytest.skip("qemu-aarch64 is missing: apt-get install qemu-user")
    if not (AARCH64_SYSROOT / "lib" / "ld-linux-aarch64.so.1").exists():
        pytest.skip(f"no aarch64 glibc in {AARCH64_SYSROOT}: apt-get install libc6-arm64-cross")
    exe = _harness(_zig(), "aarch64-linux", harness_dir)
    library = unpacked[3] / "binaries" / "aarch64-linux" / "wmr_robot.so"
    rows = _run(["qemu-aarch64", "-L", str(AARCH64_SYSROOT), str(exe), str(library),
                 *_arguments(built.fmus[3])])
    assert _agree(rows, linux64[3]) < 1e-12


@pytest.mark.parametrize("version", [2, 3])
def test_win64_binary_under_wine_gives_the_linux64_result(
        built: BuildResult, unpacked: dict[int, Path], harness_dir: Path,
        linux64: dict[int, np.ndarray], version: int,
        tmp_path_factory: pytest.TempPathFactory) -> None:
    wine = shutil.which("wine") or shutil.which("wine64")
    if wine is None:
        pytest.skip("wine is missing: apt-get install wine (optional in CI)")
    exe = _harness(_zig(), "x86_64-windows", harness_dir)
    folder = "win64" if version == 2 else "x86_64-windows"
    library = unpacked[version] / "binaries" / folder / "wmr_robot.dll"
    prefix = tmp_path_factory.getbasetemp() / "wineprefix"  # never the user's ~/.wine
    env = {**os.environ, "WINEPREFIX": str(prefix), "WINEDEBUG": "-all", "DISPLAY": ""}
    rows = _run([wine, str(exe), "Z:" + str(library).replace("/", "\\"),
                 *_arguments(built.fmus[version])], env=env)
    assert _agree(rows, linux64[version]) < 1e-12


def test_build_prints_paths_on_stdout_and_what_each_fmu_offers_on_stderr(
        built: BuildResult, capsys: pytest.CaptureFixture[str]) -> None:
    from wmr.cli import main

    _zig()
    assert main(["fmu", "build", "--out", str(built.fmus[2].parent)]) == 0
    captured = capsys.readouterr()
    assert [Path(p) for p in captured.out.splitlines()] == [
        built.fmus[2], built.fmus[3], built.controllers[2], built.controllers[3]]
    err = captured.err.splitlines()
    assert len(err) == 4
    for line, name, version in zip(err, ("wmr_robot", "wmr_robot", "wmr_controller",
                                         "wmr_controller"), (2, 3, 2, 3), strict=True):
        assert line.startswith(f"{name}-fmi{version}.fmu: FMI {version}.0, co-simulation")
        if version == 2:
            assert line.split("binaries for ")[1].startswith("linux64 win64 darwin64 (")
        else:
            assert line.endswith("binaries for " + " ".join(ALL))
    # Model Exchange is the robot's only: the controller is a sampled-data system.
    assert ["model exchange" in line for line in err] == [True, True, False, False]

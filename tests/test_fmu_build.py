"""The Modelica-to-FMU build: outputs, reuse, validation, model descriptions, sources."""

from __future__ import annotations

import re
import stat
import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from wmr.adapters.fmi.archive import (
    MAX_MODEL_DESCRIPTION_BYTES,
    MAX_XML_BYTES,
    Budget,
    MiB,
    check_archive,
    open_archive,
)
from wmr.adapters.fmi.robot import FmuPlant
from wmr.build.fmus import BuildResult, build_fmus
from wmr.cli import main
from wmr.infra.errors import FmuError

INTERFACE = {  # the public interface (docs/formats.md)
    "tau_r": ("input", "N.m"), "tau_l": ("input", "N.m"),
    "x": ("output", "m"), "y": ("output", "m"), "theta": ("output", "rad"),
    "v": ("output", "m/s"), "omega": ("output", "rad/s"),
    "omega_r": ("output", "rad/s"), "omega_l": ("output", "rad/s"),
    "phi_r": ("output", "rad"), "phi_l": ("output", "rad"),
    "x_G": ("output", "m"), "y_G": ("output", "m"),
    "m": ("parameter", "kg"), "r": ("parameter", "m"), "L": ("parameter", "m"),
    "l": ("parameter", "m"), "Ig": ("parameter", "kg.m2"), "Iwm": ("parameter", "kg.m2"),
    "b_f": ("parameter", "N.m.s/rad"), "tau_c": ("parameter", "N.m"),
    "x0": ("parameter", "m"), "y0": ("parameter", "m"), "theta0": ("parameter", "rad"),
    "v0": ("parameter", "m/s"), "omega0": ("parameter", "rad/s"),
}
PAPER_DEFAULTS = {"m": 25.0, "r": 0.15, "L": 0.3, "l": 0.35, "Ig": 0.25, "Iwm": 0.01,
                  "b_f": 0.0, "tau_c": 0.0}


def test_both_fmus_pass_fmpy_validation(built: BuildResult) -> None:
    assert sorted(built.fmus) == [2, 3]
    for path in built.fmus.values():
        assert validate_fmu(str(path)) == []


def test_rebuild_is_skipped_when_nothing_changed(built: BuildResult, fmu_dir: Path) -> None:
    again = build_fmus(fmu_dir)
    assert again.reused
    assert again.digest == built.digest
    assert again.fmus == built.fmus
    assert again.controllers == built.controllers


def test_cli_prints_one_path_per_line(fmu_dir: Path, built: BuildResult,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fmu", "build", "--out", str(fmu_dir)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [Path(p) for p in lines] == [built.fmus[2], built.fmus[3], built.controllers[2],
                                        built.controllers[3]]


@pytest.mark.parametrize("version", [2, 3])
def test_model_description_has_the_public_interface(built: BuildResult, version: int) -> None:
    md = read_model_description(str(built.fmus[version]))
    assert md.fmiVersion == f"{version}.0"
    variables = {v.name: v for v in md.modelVariables}
    for name, (causality, unit) in INTERFACE.items():
        assert variables[name].causality == causality, name
        assert variables[name].unit == unit, name
    for name, value in PAPER_DEFAULTS.items():
        assert float(variables[name].start) == value, name
    units = {u.name for u in md.unitDefinitions}
    assert {v.unit for v in md.modelVariables if v.unit} <= units
    vrs = [v.valueReference for v in md.modelVariables]
    assert len(vrs) == len(set(vrs))
    assert md.defaultExperiment is not None and float(md.defaultExperiment.stepSize) == 0.01
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert {u.variable.name for u in md.outputs} == {n for n, (c, _) in INTERFACE.items()
                                             if c == "output"} | {"E_kin"}
    token = md.guid
    assert token.startswith("{") and token[1:9] == built.digest[:8]


def test_fmi2_and_fmi3_share_guid_and_value_references(built: BuildResult) -> None:
    md2 = read_model_description(str(built.fmus[2]))
    md3 = read_model_description(str(built.fmus[3]))
    assert md2.guid == md3.guid
    refs2 = {v.name: v.valueReference for v in md2.modelVariables}
    refs3 = {v.name: v.valueReference for v in md3.modelVariables}
    # FMI 3 requires the independent variable; FMI 2 leaves it out (optional there, and FMI
    # Library reads its missing start as an error: docs/fmu.md), but keeps its reference free
    assert refs3.pop("time") == 0 and "time" not in refs2 and 0 not in refs2.values()
    assert refs2 == refs3


@pytest.mark.parametrize("version", [2, 3])
def test_only_fmi_symbols_are_exported(built: BuildResult, version: int, tmp_path: Path) -> None:
    with zipfile.ZipFile(built.fmus[version]) as zf:
        so = next(n for n in zf.namelist() if n.endswith(".so"))
        (tmp_path / "lib.so").write_bytes(zf.read(so))
    out = subprocess.run(["nm", "-D", "--defined-only", str(tmp_path / "lib.so")],
                         capture_output=True, text=True, check=True).stdout
    names = [line.split()[-1] for line in out.splitlines() if line.strip()]
    assert names and all(n.startswith("fmi") for n in names if not n.startswith("_"))
    assert any(n.startswith(f"fmi{version}DoStep") for n in names)


@pytest.mark.parametrize("version", [2, 3])
def test_sources_in_the_fmu_compile_on_their_own(built: BuildResult, version: int,
                                                 tmp_path: Path) -> None:
    import fmpy

    with zipfile.ZipFile(built.fmus[version]) as zf:
        zf.extractall(tmp_path)
    src = tmp_path / "sources"
    if version == 2:
        root = ET.parse(tmp_path / "modelDescription.xml").getroot()
        names = [f.get("name") for f in root.iter("File")]
        # Model Exchange and Co-Simulation list the same sources
        assert names[: len(names) // 2] == names[len(names) // 2:]
        names = names[: len(names) // 2]
    else:
        root = ET.parse(src / "buildDescription.xml").getroot()
        names = [f.get("name") for f in root.iter("SourceFile")]
    headers = Path(fmpy.__file__).parent / "c-code"
    cmd = ["gcc", "-shared", "-fPIC", "-O1", f"-I{src}", f"-I{headers}",
           *(str(src / str(n)) for n in names), "-o", str(tmp_path / "rebuilt.so"), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True)
    assert (tmp_path / "rebuilt.so").stat().st_size > 0


def _zip(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return path


def test_hostile_archives_are_refused(tmp_path: Path) -> None:
    with pytest.raises(FmuError, match="outside"):
        check_archive(_zip(tmp_path / "slip.fmu",
                           {"modelDescription.xml": b"<x/>", "../evil.so": b"x"}))
    with pytest.raises(FmuError, match="outside"):
        check_archive(_zip(tmp_path / "abs.fmu",
                           {"modelDescription.xml": b"<x/>", "/etc/evil": b"x"}))
    with pytest.raises(FmuError, match="no modelDescription"):
        check_archive(_zip(tmp_path / "empty.fmu", {"readme.txt": b"x"}))
    (tmp_path / "text.fmu").write_text("not a zip")
    with pytest.raises(FmuError, match="not a zip"):
        check_archive(tmp_path / "text.fmu")
    with pytest.raises(FmuError, match="no such FMU"):
        FmuPlant(tmp_path / "missing.fmu")


def test_hostile_archive_budget_is_exact_and_refusals_name_the_member(tmp_path: Path) -> None:
    """The total budget admits exactly its bytes and not one more; a member read past its
    limit is refused by name; a missing member is a KeyError naming it."""
    fmu = _zip(tmp_path / "exact.fmu", {"modelDescription.xml": b"<x/>", "data.bin": b"d" * 96})
    assert sorted(check_archive(fmu, Budget(total_bytes=100))) == ["data.bin",
                                                                   "modelDescription.xml"]
    with pytest.raises(FmuError, match="unpacks to more than 99 bytes in all"):
        check_archive(fmu, Budget(total_bytes=99))
    assert len(check_archive(fmu, Budget(member_bytes=96))) == 2  # data.bin: 96 bytes exactly
    with pytest.raises(FmuError, match=rf"^{re.escape(str(fmu))}: member 'data\.bin' unpacks "
                                       "to more than 95 bytes"):
        check_archive(fmu, Budget(member_bytes=95))
    nested = _zip(tmp_path / "nested.fmu", {"modelDescription.xml": b"<x/>", "a": b"1",
                                            "a/b": b"2"})
    with pytest.raises(FmuError, match=r"member 'a/b' is under 'a', which is a file"):
        check_archive(nested)
    with open_archive(fmu) as archive:
        with pytest.raises(FmuError, match=r"member 'data\.bin' unpacks to more than 10 bytes"):
            list(archive.chunks("data.bin", limit=10))
        with pytest.raises(KeyError, match="nope"):
            next(archive.chunks("nope"))


def test_hostile_archive_members_are_refused_by_name(tmp_path: Path) -> None:
    """A link and a damaged member: the one line names the member (and what is wrong)."""
    link = tmp_path / "link.fmu"
    with zipfile.ZipFile(link, "w") as zf:
        zf.writestr("modelDescription.xml", b"<x/>")
        info = zipfile.ZipInfo("binaries/linux64/robot.so")
        info.create_system = 3
        info.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(info, b"/etc/passwd")
    with pytest.raises(FmuError, match=r"member 'binaries/linux64/robot\.so' is a symbolic link"):
        check_archive(link)
    damaged = _zip(tmp_path / "damaged.fmu", {"modelDescription.xml": b"<x/>",
                                              "data.bin": b"0123456789" * 10})
    raw = bytearray(damaged.read_bytes())
    at = raw.index(b"0123456789")
    raw[at] ^= 0x01  # a stored member: one bit of its data flipped, its CRC no longer matches
    damaged.write_bytes(bytes(raw))
    with pytest.raises(FmuError, match=r"member 'data\.bin' is damaged"):
        check_archive(damaged)


def test_hostile_archive_member_count_is_counted_not_read_from_the_end_record(
        tmp_path: Path) -> None:
    """As many members as the budget is fine; one more is refused, also when the end record
    claims fewer entries than the directory holds."""
    fmu = _zip(tmp_path / "three.fmu", {"modelDescription.xml": b"<x/>", "a": b"a", "b": b"b"})
    assert len(check_archive(fmu, Budget(members=3))) == 3
    raw = bytearray(fmu.read_bytes())
    eocd = raw.rindex(b"PK\x05\x06")
    raw[eocd + 8:eocd + 12] = (1).to_bytes(2, "little") * 2  # "1 entry" on the disk, in all
    fmu.write_bytes(bytes(raw))
    with pytest.raises(FmuError, match=rf"^{re.escape(str(fmu))}: .*3 members, more than 2"):
        check_archive(fmu, Budget(members=2))


def test_hostile_archive_encryption_and_other_compressions_are_refused_by_name(
        tmp_path: Path) -> None:
    enc = tmp_path / "encrypted.fmu"
    _zip(enc, {"modelDescription.xml": b"<x/>", "secret.bin": b"x"})
    raw = bytearray(enc.read_bytes())
    entry = raw.rindex(b"PK\x01\x02")  # the last directory entry: secret.bin's
    raw[entry + 8] |= 0x1  # general purpose flag bit 0: encrypted (zipfile cannot write it)
    enc.write_bytes(bytes(raw))
    with pytest.raises(FmuError, match=r"member 'secret\.bin' is encrypted"):
        check_archive(enc)
    bz = tmp_path / "bzip2.fmu"
    with zipfile.ZipFile(bz, "w", compression=zipfile.ZIP_BZIP2) as zf:
        zf.writestr("modelDescription.xml", b"<x/>")
    with pytest.raises(FmuError, match=r"member 'modelDescription\.xml' uses compression method "
                                       r"12 \(FMI and SSP archives are stored or deflated\)"):
        check_archive(bz)


def test_hostile_archive_budget_of_members_is_shared_and_duplicates_are_named(
        tmp_path: Path) -> None:
    """The member budget counts down across the archives that share it (a package and the
    FMUs inside); two names for one file are refused with both names; an empty folder is
    extracted as a folder."""
    fmu = _zip(tmp_path / "three.fmu", {"modelDescription.xml": b"<x/>", "a": b"a", "b": b"b"})
    shared = Budget(members=5)
    check_archive(fmu, shared)
    with pytest.raises(FmuError, match="3 members, more than 2"):
        check_archive(fmu, shared)
    dup = _zip(tmp_path / "dup.fmu", {"modelDescription.xml": b"<x/>",
                                      "binaries/Robot.so": b"1", "binaries/robot.so": b"2"})
    with pytest.raises(FmuError, match=r"members 'binaries/Robot\.so' and 'binaries/robot\.so' "
                                       r"are the same file \(a duplicate\)"):
        check_archive(dup)
    folder = _zip(tmp_path / "folder.fmu", {"modelDescription.xml": b"<x/>", "resources/": b""})
    dest = tmp_path / "out"
    dest.mkdir()
    with open_archive(folder) as archive:
        archive.extract(dest)
    assert (dest / "resources").is_dir() and not any((dest / "resources").iterdir())


def test_hostile_archive_members_inflate_in_bounded_chunks(tmp_path: Path) -> None:
    """A member is counted as it inflates, chunk by chunk (a bomb is refused before it is in
    memory), never read whole."""
    fmu = _zip(tmp_path / "long.fmu", {"modelDescription.xml": b"<x/>",
                                       "zeros.bin": bytes(5 * MiB // 2)})
    with open_archive(fmu) as archive:
        sizes = [len(c) for c in archive.chunks("zeros.bin")]
    assert sum(sizes) == 5 * MiB // 2 and len(sizes) == 3 and max(sizes) <= MiB


def test_a_model_description_within_its_own_bound_is_not_refused(tmp_path: Path) -> None:
    """The model description has its own bound (16 MiB: fmpy parses it whole at about 25
    bytes of memory a byte; large real ones are about 10 MB), below the SSP documents' (32
    MiB): a model description of exactly that size is taken."""
    assert MAX_MODEL_DESCRIPTION_BYTES < MAX_XML_BYTES
    head, tail = b"<fmiModelDescription>", b"</fmiModelDescription>"
    md = head + b" " * (MAX_MODEL_DESCRIPTION_BYTES - len(head) - len(tail)) + tail
    fmu = _zip(tmp_path / "large-md.fmu", {"modelDescription.xml": md})
    assert check_archive(fmu) == ["modelDescription.xml"]


# ------------------------------------------------------------- platforms and progress (issue 21)


def test_the_implicit_build_of_a_run_is_for_this_machine_only(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``wmr run``, ``wmr batch`` and the API build through ``default_fmu``: the host's
    binaries only (seconds), not the five platforms of ``wmr fmu build`` (minutes)."""
    import wmr.build.fmus as fmus
    from wmr.apps.run import default_controller_fmu, default_fmu

    asked: list[object] = []
    built = BuildResult({2: Path("r2.fmu"), 3: Path("r3.fmu")}, "digest", True,
                        controllers={2: Path("c2.fmu"), 3: Path("c3.fmu")})

    def spy(*args: object, **kwargs: object) -> BuildResult:
        asked.append(kwargs.get("platforms", "all"))
        return built

    monkeypatch.setattr(fmus, "build_fmus", spy)
    default_fmu(3)
    default_controller_fmu(2)
    assert asked == ["host", "host"]


def test_host_and_full_builds_have_their_own_cache_folders() -> None:
    from wmr.build.fmus import default_out_dir
    from wmr.build.platforms import host_platform
    from wmr.infra import paths

    host = host_platform()
    assert host is not None
    assert default_out_dir("all") == paths.default_fmu_dir()
    assert default_out_dir("host") == paths.default_fmu_dir().with_name(f"fmu-{host.name}")
    assert default_out_dir("host") == default_out_dir(host.name)
    assert default_out_dir("x86_64-windows,x86_64-linux").name == \
        "fmu-x86_64-linux+x86_64-windows"


def test_platform_choices_are_parsed_and_bad_ones_named() -> None:
    from wmr.build.platforms import PLATFORMS, parse_platforms
    from wmr.infra.errors import ConfigError

    assert parse_platforms("all") is None
    assert parse_platforms(["aarch64-darwin", "x86_64-linux"]) == (PLATFORMS[0], PLATFORMS[4])
    assert parse_platforms("x86_64-windows, x86_64-windows") == (PLATFORMS[2],)
    for bad in ("win64", "", "all,x86_64-linux"):
        with pytest.raises(ConfigError, match="platforms"):
            parse_platforms(bad)


def test_the_host_compiler_is_preferred_for_a_host_only_build() -> None:
    """gcc builds the host's binaries in seconds where zig first builds its C libraries."""
    import shutil

    from wmr.build.platforms import find_compiler, host_platform, parse_platforms

    if shutil.which("gcc") is None or host_platform() is None:
        pytest.skip("needs gcc on a Linux host")
    assert not find_compiler(None, parse_platforms("host")).cross


@pytest.mark.parametrize("argv, option", [
    (["fmu", "build", "--platforms", "win64"], "--platforms"),
    (["fmu", "build", "--platforms", "host", "--out", "/proc/wmr-fmus"], "--out"),
    (["fmu", "crosscheck", "--out", "x", "--platforms", "linux"], "--platforms"),
])
def test_bad_platforms_and_folders_are_one_line_errors(
        argv: list[str], option: str, capsys: pytest.CaptureFixture[str]) -> None:
    if option == "--out" and not Path("/proc/self").exists():
        pytest.skip("needs /proc, where no folder can be created")
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"wmr: error: {option}:"), err


def _fake_compile(seconds: float) -> object:
    """A compiler that takes ``seconds`` per library and writes an empty one."""
    import time

    def compile_(compiler: object, target: object, sources: object, include: object,
                 output: Path) -> None:
        time.sleep(seconds)
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_bytes(b"")

    return compile_


def test_a_build_reports_each_step_and_says_it_still_runs(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A compile longer than the progress interval is reported while it runs, and each
    library when it is done: a first build is never silent for minutes."""
    import wmr.build.fmus as fmus

    monkeypatch.setattr(fmus, "PROGRESS_INTERVAL_S", 0.05)
    monkeypatch.setattr(fmus, "_compile", _fake_compile(0.4))
    lines: list[str] = []
    result = fmus.build_fmus(tmp_path, platforms="host", validate=False,
                             on_build=lines.append)
    assert not result.reused and len(result.platforms) == 1
    assert lines[0].startswith(f"building the robot and controller FMUs for "
                               f"{result.platforms[0]}")
    for product in ("robot", "controller"):
        assert f"{product}: generating the C sources" in lines
        assert sum(f"{product}: still compiling" in line for line in lines) >= 2, lines
        assert f"{product}: compiled FMI 3 {result.platforms[0]} " in "\n".join(lines)
        assert any(line.startswith(f"{product}: compiled ") and "(2/2," in line
                   for line in lines)
    assert lines[-1].startswith("built the FMUs in")
    # reused: nothing to say
    lines.clear()
    assert fmus.build_fmus(tmp_path, platforms="host", validate=False,
                           on_build=lines.append).reused
    assert lines == []


def test_waiting_on_another_build_is_reported(monkeypatch: pytest.MonkeyPatch,
                                              tmp_path: Path) -> None:
    """A process that waits on another's build of the same folder says so, repeatedly."""
    import fcntl
    import threading
    import time

    import wmr.build.fmus as fmus

    monkeypatch.setattr(fmus, "PROGRESS_INTERVAL_S", 0.05)
    lines: list[str] = []
    entered = threading.Event()

    def waiter() -> None:
        with fmus._locked(tmp_path, lines.append):
            entered.set()

    with open(tmp_path / ".wmr-build.lock", "w") as other:  # the other process's lock
        fcntl.flock(other, fcntl.LOCK_EX)
        thread = threading.Thread(target=waiter)
        thread.start()
        for _ in range(1000):  # a bound, so that a silent wait fails rather than hangs
            if sum("waiting for another process's build" in line for line in lines) >= 3:
                break
            time.sleep(0.01)
        assert not entered.is_set()
        fcntl.flock(other, fcntl.LOCK_UN)
        assert sum("waiting for another process's build" in line for line in lines) >= 3
    thread.join(10)
    assert entered.is_set()
    assert lines[-1].startswith("the other build finished after")


def test_a_host_only_build_says_nothing_of_platforms_it_was_not_asked_for(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``wmr fmu build --platforms host`` printed "(FMI 2.0 names no platform for
    aarch64-linux, aarch64-darwin)" for a build that was asked for neither."""
    from wmr.build.platforms import host_platform

    host = host_platform()
    if host is None or host.fmi2 is None:
        pytest.skip("needs a host that FMI 2.0 names")
    assert main(["fmu", "build", "--platforms", "host", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    fmi2 = [line for line in err.splitlines() if ": FMI 2.0, " in line]
    assert len(fmi2) == 2 and all(f"binaries for {host.fmi2}" in line for line in fmi2), err
    assert "names no platform" not in err and "aarch64" not in err, err


@pytest.mark.parametrize(("requested", "said"), [
    (None, " (no aarch64-linux, aarch64-darwin binaries: FMI 2.0 has no standard platform name "
           "for them; the FMI 3.0 FMU carries them)"),
    (("x86_64-linux", "aarch64-linux"), " (no aarch64-linux binaries: FMI 2.0 has no standard "
                                        "platform name for it; the FMI 3.0 FMU carries it)"),
    (("x86_64-linux",), ""),
])
def test_the_fmi2_line_says_what_is_done_with_the_platforms_fmi2_cannot_name(
        requested: tuple[str, ...] | None, said: str) -> None:
    """The FMI 2.0 line said "(FMI 2.0 names no platform for aarch64-linux, ...)": as if the
    standard forbade the platform, and not what the build did.  FMI 2.0 has no standard name
    for aarch64: its binaries are left out of the FMI 2.0 FMU and are in the FMI 3.0 one."""
    from wmr.build.fmus import FmuSummary
    from wmr.build.platforms import PLATFORMS

    summary = FmuSummary(Path("wmr_robot-fmi2.fmu"), "2.0", ("co-simulation",),
                         tuple(p.fmi2 for p in PLATFORMS if p.fmi2 is not None
                               and (requested is None or p.name in requested)))
    binaries = " ".join(summary.platforms)
    assert summary.line(requested) == \
        f"wmr_robot-fmi2.fmu: FMI 2.0, co-simulation, binaries for {binaries}{said}"

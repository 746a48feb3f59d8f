"""Archives from strangers (issue 17): every FMU and SSP package goes through one door
(``wmr.adapters.fmi.archive.open_archive``) that refuses, with one line naming the file and
what is wrong, any member that would be written outside its folder, any link, duplicate,
bomb or hostile XML, before a master (libcosim) ever sees the archive.

Run as a script, this module writes every hostile package at full size (the SSD that inflates
to 2 GiB, ...) into a folder, for measuring peak memory with ``/usr/bin/time -v``
(docs/reliability.md)::

    python tests/test_hostile_archives.py GOOD.ssp OUT_DIR
"""

from __future__ import annotations

import re
import stat
import struct
import sys
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

MiB = 1 << 20


# ------------------------------------------------------------------ a zip writer for attacks


@dataclass
class Member:
    """One member as it is written, lies included (``crc``, ``size`` and ``raw`` override
    what ``data`` would give)."""

    name: str
    data: bytes = b""
    raw: bytes | None = None
    method: int = zipfile.ZIP_DEFLATED
    crc: int | None = None
    size: int | None = None
    mode: int = stat.S_IFREG | 0o644
    create_system: int = 3
    windows_attr: int = 0
    flags: int = 0


def write_zip(path: Path, members: list[Member]) -> Path:
    """Write ``members`` as a zip file, exactly as given (duplicates, links, bad names)."""
    local, central = bytearray(), bytearray()
    for m in members:
        name = m.name.encode("utf-8")
        if m.raw is not None:
            raw = m.raw
        elif m.method == zipfile.ZIP_DEFLATED:
            c = zlib.compressobj(9, zlib.DEFLATED, -15)
            raw = c.compress(m.data) + c.flush()
        else:
            raw = m.data
        crc = zlib.crc32(m.data) if m.crc is None else m.crc
        size = len(m.data) if m.size is None else m.size
        flags = m.flags | 0x800  # UTF-8 names
        offset = len(local)
        local += struct.pack("<4s5H3L2H", b"PK\x03\x04", 20, flags, m.method, 0, 0x21, crc,
                             len(raw), size, len(name), 0) + name + raw
        external = (m.mode << 16) | m.windows_attr
        central += struct.pack("<4s6H3L5H2L", b"PK\x01\x02", (m.create_system << 8) | 20, 20,
                               flags, m.method, 0, 0x21, crc, len(raw), size, len(name), 0, 0,
                               0, 0, external, offset) + name
    n = len(members)
    end = struct.pack("<4s4H2LH", b"PK\x05\x06", 0, 0, n, n, len(central), len(local), 0)
    path.write_bytes(bytes(local + central + end))
    return path


def spaces_bomb(name: str, prefix: bytes, mib: int, suffix: bytes) -> Member:
    """A deflated member of ``prefix``, ``mib`` MiB of spaces and ``suffix``: a few kB that
    inflate to ``mib`` MiB (blocks flushed with ``Z_FULL_FLUSH`` concatenate)."""
    def block(data: bytes) -> bytes:
        c = zlib.compressobj(9, zlib.DEFLATED, -15)
        return c.compress(data) + c.flush(zlib.Z_FULL_FLUSH)

    chunk = b" " * MiB
    raw = block(prefix) + block(chunk) * mib + block(suffix) + b"\x03\x00"  # final empty block
    crc = zlib.crc32(prefix)
    for _ in range(mib):
        crc = zlib.crc32(chunk, crc)
    crc = zlib.crc32(suffix, crc)
    return Member(name, raw=raw, crc=crc, size=len(prefix) + mib * MiB + len(suffix))


def members_of(archive: Path | bytes) -> dict[str, bytes]:
    import io

    source = io.BytesIO(archive) if isinstance(archive, bytes) else archive
    with zipfile.ZipFile(source) as zf:
        return {i.filename: zf.read(i) for i in zf.infolist()}


def zip_bytes(members: list[Member], tmp: Path) -> bytes:
    return write_zip(tmp, members).read_bytes()


# ------------------------------------------------------------------ the hostile packages

ROBOT_FMU = "resources/wmr_robot-fmi2.fmu"
SSD = "SystemStructure.ssd"


def slip_name(victim: Path) -> str:
    """A member name that climbs out of any extraction folder to ``victim``."""
    return "resources/" + "../" * 40 + str(victim).lstrip("/")


def package(good: Path, out: Path, extra: list[Member] | None = None,
            replace: dict[str, Member] | None = None, drop: tuple[str, ...] = ()) -> Path:
    """``good`` with members replaced, dropped and added (after the others)."""
    members = [replace.get(n, Member(n, d)) if replace else Member(n, d)
               for n, d in members_of(good).items() if n not in drop]
    return write_zip(out, members + (extra or []))


def nested(good: Path, out: Path, extra: list[Member], scratch: Path) -> Path:
    """``good`` whose robot FMU carries the ``extra`` members too."""
    fmu = [Member(n, d) for n, d in members_of(members_of(good)[ROBOT_FMU]).items()]
    data = zip_bytes(fmu + extra, scratch / "nested.fmu")
    return package(good, out, replace={ROBOT_FMU: Member(ROBOT_FMU, data,
                                                         method=zipfile.ZIP_STORED)})


def ssd_with(good: Path, out: Path, edit: Callable[[bytes], bytes]) -> Path:
    ssd = members_of(good)[SSD]
    return package(good, out, replace={SSD: Member(SSD, edit(ssd))})


BILLION_LAUGHS = (b'<?xml version="1.0"?>\n<!DOCTYPE lolz [<!ENTITY lol "lol">'
                  + b"".join(b'<!ENTITY lol%d "%s">' % (i, b"&lol%d;" % (i - 1) * 10
                                                         if i > 1 else b"&lol;" * 10)
                             for i in range(1, 10))
                  + b"]>\n<lolz>&lol9;</lolz>\n")


def _components(n: int) -> Callable[[bytes], bytes]:
    def edit(ssd: bytes) -> bytes:
        head, tail = ssd.split(b"</ssd:Elements>", 1)
        comp = (b'<ssd:Component name="c%d" type="application/x-fmu-sharedlibrary" '
                b'source="resources/wmr_robot-fmi2.fmu"/>')
        return head + b"".join(comp % i for i in range(n)) + b"</ssd:Elements>" + tail
    return edit


#: case -> (builder(good, out, victim, scratch, full_size), what the one line says).  The
#: bombs are smaller in the tests than at full size (``full_size``): the bounds are the same.
Builder = Callable[[Path, Path, Path, Path, bool], Path]
CASES: dict[str, tuple[Builder, str]] = {
    "ssp-slip": (lambda g, o, v, s, f: package(g, o, [Member(slip_name(v), b"owned")]),
                 "contains '..'"),
    "ssp-absolute": (lambda g, o, v, s, f: package(g, o, [Member(str(v), b"owned")]),
                     "is an absolute path"),
    "ssp-backslash": (lambda g, o, v, s, f: package(
        g, o, [Member(slip_name(v).replace("/", "\\"), b"owned")]), "backslash"),
    "ssp-drive": (lambda g, o, v, s, f: package(g, o, [Member("C:/x/existing.txt", b"x")]),
                  "a drive"),
    "ssp-symlink-then-file": (lambda g, o, v, s, f: package(g, o, [
        Member("resources/out", str(v.parent).encode(), method=zipfile.ZIP_STORED,
               mode=stat.S_IFLNK | 0o777),
        Member("resources/out/existing.txt", b"owned")]), "is a symbolic link"),
    "ssp-windows-link": (lambda g, o, v, s, f: package(g, o, [
        Member("resources/out", b"", create_system=0, mode=0, windows_attr=0x400)]),
        "reparse point"),
    "ssp-fifo": (lambda g, o, v, s, f: package(g, o, [
        Member("resources/fifo", b"", mode=stat.S_IFIFO | 0o644)]), "special file"),
    "ssp-duplicate-ssd": (lambda g, o, v, s, f: package(g, o, [Member(SSD, b"<x/>")]),
                          "a duplicate"),
    "ssp-case-duplicate": (lambda g, o, v, s, f: package(
        g, o, [Member("resources/Robot.ssv", b"<x/>")]), "a duplicate"),
    "ssp-file-under-file": (lambda g, o, v, s, f: package(
        g, o, [Member(f"{ROBOT_FMU}/x", b"x")]), "which is a file"),
    "ssp-encrypted": (lambda g, o, v, s, f: package(g, o, [Member("resources/e", b"x",
                                                                  flags=0x1)]), "encrypted"),
    "ssp-bzip2": (lambda g, o, v, s, f: package(g, o, [Member("resources/b", b"x",
                                                              method=12)]),
                  "compression method 12"),
    "ssp-10001-members": (lambda g, o, v, s, f: package(
        g, o, [Member(f"resources/m{i}", b"") for i in range(10_001)]), "more than 10000"),
    "ssp-ssd-bomb": (lambda g, o, v, s, f: package(g, o, drop=(SSD,), extra=[spaces_bomb(
        SSD, b'<?xml version="1.0"?><a>', 2048 if f else 40, b"</a>")]),
        "unpacks to more than 33554432 bytes"),
    "ssp-lying-size": (lambda g, o, v, s, f: package(g, o, extra=[Member(
        "resources/lie.txt", b" " * (2 * MiB), size=10)]), "is damaged"),
    "ssp-total-bomb": (lambda g, o, v, s, f: package(g, o, extra=[spaces_bomb(
        f"resources/b{i}.txt", b"", 256 if f else 30, b"") for i in range(3)]), "in all"),
    "ssd-billion-laughs": (lambda g, o, v, s, f: package(g, o, replace={
        SSD: Member(SSD, BILLION_LAUGHS)}), "document type declaration"),
    "ssd-external-entity": (lambda g, o, v, s, f: package(g, o, replace={SSD: Member(
        SSD, b'<?xml version="1.0"?><!DOCTYPE a [<!ENTITY x SYSTEM "file://%s">]><a>&x;</a>'
        % str(v).encode())}), "document type declaration"),
    "ssd-deep": (lambda g, o, v, s, f: package(g, o, replace={SSD: Member(
        SSD, b"<a>" * 100_000 + b"</a>" * 100_000)}), "nested more than 256 deep"),
    "ssd-3000-components": (lambda g, o, v, s, f: ssd_with(g, o, _components(3000)),
                            "3002 components, more than 64"),
    "ssv-source-outside": (lambda g, o, v, s, f: ssd_with(g, o, lambda d: d.replace(
        b'source="resources/robot.ssv"', b'source="../../robot.ssv"')),
        "is not a path inside the package"),
    "fmu-source-absolute": (lambda g, o, v, s, f: ssd_with(g, o, lambda d: d.replace(
        b'source="resources/wmr_robot-fmi2.fmu"', b'source="/tmp/wmr_robot-fmi2.fmu"')),
        "is not a path inside the package"),
    "nested-slip": (lambda g, o, v, s, f: nested(g, o, [Member(slip_name(v), b"owned")], s),
                    "resources/wmr_robot-fmi2.fmu: member"),
    "nested-symlink": (lambda g, o, v, s, f: nested(g, o, [Member(
        "binaries/linux64/evil.so", str(v).encode(), mode=stat.S_IFLNK | 0o777)], s),
        "is a symbolic link"),
    "nested-bomb": (lambda g, o, v, s, f: nested(g, o, [spaces_bomb(
        f"resources/b{i}.bin", b"", 300 if f else 40, b"") for i in range(2)], s), "in all"),
    "nested-md-entity": (lambda g, o, v, s, f: nested_md(g, o, s), "document type"),
    "nested-not-zip": (lambda g, o, v, s, f: package(g, o, replace={
        ROBOT_FMU: Member(ROBOT_FMU, b"not a zip")}), "is not an FMU"),
}


def nested_md(good: Path, out: Path, scratch: Path) -> Path:
    fmu = members_of(members_of(good)[ROBOT_FMU])
    md = fmu["modelDescription.xml"]
    fmu["modelDescription.xml"] = md.replace(
        b"?>", b'?><!DOCTYPE f [<!ENTITY x SYSTEM "file:///etc/passwd">]>', 1)
    data = zip_bytes([Member(n, d) for n, d in fmu.items()], scratch / "md.fmu")
    return package(good, out, replace={ROBOT_FMU: Member(ROBOT_FMU, data,
                                                         method=zipfile.ZIP_STORED)})


# ------------------------------------------------------------------ the tests


@pytest.fixture(scope="module")
def good_ssp(tmp_path_factory: pytest.TempPathFactory, built: object) -> Path:
    from wmr.adapters.ssp.export import export_ssp
    from wmr.config.scenario import load_scenario

    out = tmp_path_factory.mktemp("hostile") / "fig11.ssp"
    export_ssp(load_scenario("fig11").runs[0], out, built.fmus[2],  # type: ignore[attr-defined]
               built.controllers[2])  # type: ignore[attr-defined]
    return out


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    folder = tmp_path / "outside"
    folder.mkdir()
    path = folder / "existing.txt"
    path.write_bytes(b"precious")
    return path


def _small_bombs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests use bombs of 40-96 MiB against budgets of 64 MiB; full-size bombs (2 GiB) and
    budgets (512 MiB) are measured by running this module as a script."""
    from wmr.adapters.fmi import archive
    from wmr.adapters.ssp import package as ssp_package

    small = 64 * MiB
    monkeypatch.setattr(ssp_package, "Budget",
                        lambda: archive.Budget(total_bytes=small, member_bytes=small),
                        raising=False)  # raising: the code before the door had no Budget


def _build(case: str, good: Path, tmp_path: Path, victim: Path) -> Path:
    builder = CASES[case][0]
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    return builder(good, tmp_path / f"{case}.ssp", victim, scratch, False)


@pytest.mark.parametrize("case", list(CASES))
def test_a_hostile_package_is_refused_in_one_line_and_writes_nothing_outside(
        case: str, good_ssp: Path, tmp_path: Path, victim: Path,
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from wmr.cli import main

    _small_bombs(monkeypatch)
    bad = _build(case, good_ssp, tmp_path, victim)
    out = tmp_path / "x.mcap"
    before = sorted(victim.parent.iterdir())
    code = main(["ssp", "run", str(bad), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert victim.read_bytes() == b"precious"
    assert sorted(victim.parent.iterdir()) == before
    assert code == 1 and not out.exists(), err
    lines = [line for line in err if line.startswith("wmr:")]
    assert len(lines) == 1 and str(bad) in lines[0] and CASES[case][1] in lines[0], err
    assert "internal error" not in lines[0]


@pytest.mark.parametrize("case", ["slip", "symlink", "md-entity"])
def test_wmr_ssp_export_refuses_the_fmus_wmr_run_refuses(
        case: str, good_ssp: Path, tmp_path: Path, victim: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    from wmr.cli import main

    fmu = members_of(members_of(good_ssp)[ROBOT_FMU])
    members = [Member(n, d) for n, d in fmu.items()]
    if case == "slip":
        members.append(Member(slip_name(victim), b"owned"))
    elif case == "symlink":
        members.append(Member("resources/link", b"/etc", mode=stat.S_IFLNK | 0o777))
    else:
        members = [Member(n, d.replace(b"?>", b"?><!DOCTYPE f [<!ENTITY x 'y'>]>", 1)
                          if n == "modelDescription.xml" else d) for n, d in fmu.items()]
    bad = write_zip(tmp_path / "bad.fmu", members)
    for argv in (["run", "fig11", "--fmu", str(bad), "--out", str(tmp_path / "r.mcap")],
                 ["ssp", "export", "fig11", "--robot-fmu", str(bad), "--out",
                  str(tmp_path / "p.ssp")]):
        assert main(argv) == 1, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "bad.fmu" in err[0] and "refused" in err[0], err
    assert not (tmp_path / "p.ssp").exists() and victim.read_bytes() == b"precious"


def test_libcosim_gets_a_checked_folder_never_the_package(
        good_ssp: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """What libcosim loads is a folder whose FMUs were written by us from checked members."""
    from libcosimpy.CosimExecution import CosimExecution

    from wmr.adapters.ssp.cosim import simulate_libcosim

    seen: list[Path] = []
    original = CosimExecution.from_ssp_file

    def spy(path: str, step_size: int = 0) -> object:
        folder = Path(path)
        seen.append(folder)
        assert folder.is_dir() and (folder / SSD).is_file()
        for fmu in folder.glob("resources/*.fmu"):
            with zipfile.ZipFile(fmu) as zf:  # ours: stored, every member checked
                assert {i.compress_type for i in zf.infolist()} == {zipfile.ZIP_STORED}
        return original(path, step_size=step_size)

    monkeypatch.setattr(CosimExecution, "from_ssp_file", staticmethod(spy))
    run = simulate_libcosim(good_ssp, stop_time_s=0.1, stop_at_convergence=False)
    assert seen and run.block.shape[0] == 10
    assert not seen[0].exists()  # removed after the run


def test_the_door_counts_inflated_bytes_not_the_header(tmp_path: Path) -> None:
    """A member whose header claims 10 bytes but inflates to more is refused (its CRC); the
    budget and a reader's limit are counted on the inflated bytes."""
    from wmr.adapters.fmi.archive import Budget, open_archive
    from wmr.infra.errors import FmuError

    lie = write_zip(tmp_path / "lie.zip", [Member("a", b" " * MiB, size=10)])
    with open_archive(lie, "test") as archive, pytest.raises(FmuError, match="damaged"):
        archive.check()
    honest = write_zip(tmp_path / "honest.zip", [spaces_bomb("a", b"", 8, b"")])
    with open_archive(honest, "test", Budget(total_bytes=4 * MiB)) as archive, \
            pytest.raises(FmuError, match="more than 4194304 bytes in all"):
        archive.check()
    with open_archive(honest, "test") as archive, \
            pytest.raises(FmuError, match="more than 1048576 bytes"):
        archive.read("a", limit=MiB)



# ------------------------------------------------------------------ names that become paths

#: A library that says it was loaded: its constructor runs at dlopen, before any FMI call.
EVIL_C = """#include <stdio.h>
__attribute__((constructor)) static void owned(void) {
    FILE *f = fopen("%s", "w");
    if (f) { fputs("owned", f); fclose(f); }
}
"""


@pytest.fixture
def evil_library(tmp_path: Path) -> tuple[Path, Path]:
    """``(library path without .so, marker file its constructor writes)``, outside any FMU."""
    import shutil
    import subprocess

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    folder = tmp_path / "evil"
    folder.mkdir()
    marker = tmp_path / "marker.txt"
    (folder / "evil.c").write_text(EVIL_C % marker)
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(folder / "libevil.so"),
                    str(folder / "evil.c")], check=True)
    return folder / "libevil", marker


def _with_identifier(fmu: Path, out: Path, identifier: str, interface: str) -> Path:
    """``fmu`` whose model description names ``identifier`` for ``interface`` (its
    ``CoSimulation`` or ``ModelExchange`` element): no binary is added."""
    members = members_of(fmu)
    md = members["modelDescription.xml"].decode()
    md = re.sub(f'(<{interface} [^>]*modelIdentifier=")wmr_robot"', f'\\g<1>{identifier}"',
                md)
    assert identifier in md
    members["modelDescription.xml"] = md.encode()
    return write_zip(out, [Member(n, d) for n, d in members.items()])


@pytest.mark.parametrize("fmi", [2, 3])
@pytest.mark.parametrize("case", ["absolute", "traversing", "model-exchange"])
def test_a_model_identifier_that_is_a_path_never_loads_a_library(
        case: str, fmi: int, built: object, evil_library: tuple[Path, Path], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """fmpy joins ``modelIdentifier`` onto ``binaries/<platform>/``: ``/abs/libevil`` or
    ``../../../../evil/libevil`` loaded a library from outside the extracted FMU, whose
    constructor ran before any error.  Refused at the archive door, naming the FMU and the
    field, by ``wmr run --fmu``, the plant of a batch worker and ``wmr ssp export``."""
    import tempfile

    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.cli import main
    from wmr.core.plant import Pose, RobotParams
    from wmr.infra.errors import FmuError

    library, marker = evil_library
    extraction = tmp_path / "tmp"  # the FMU's folder: tmp/wmr-fmu-*/binaries/<platform>/
    extraction.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(extraction))
    identifier = {"absolute": str(library), "traversing": "../../../../evil/libevil",
                  "model-exchange": "../../../../evil/libevil"}[case]
    interface = "ModelExchange" if case == "model-exchange" else "CoSimulation"
    good = built.fmus[fmi]  # type: ignore[attr-defined]
    bad = _with_identifier(good, tmp_path / "bad.fmu", identifier, interface)
    with pytest.raises(FmuError, match=f"bad.fmu: modelDescription.xml: its {interface} "
                                       "modelIdentifier .* is not "
                                       "a C identifier"):
        with FmuPlant(bad) as plant:  # what a batch worker opens and runs
            plant.reset(RobotParams(), Pose(0.0, 0.0, 0.0))
    for argv in (["run", "fig11", "--fmu", str(bad), "--out", str(tmp_path / "r.mcap")],
                 ["ssp", "export", "fig11", "--robot-fmu", str(bad), "--out",
                  str(tmp_path / "p.ssp")]):
        assert main(argv) == 1, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "bad.fmu" in err[0] and "modelIdentifier" in err[0], err
    assert not marker.exists(), "the library's constructor ran"
    assert not (tmp_path / "p.ssp").exists() and not (tmp_path / "r.mcap").exists()
    assert list(extraction.iterdir()) == []  # the extraction folders removed


def test_the_library_fmpy_loads_is_a_regular_file_inside_the_fmu(tmp_path: Path) -> None:
    """The last check before fmpy dlopens: the library named by the (checked) identifier is
    a regular file under ``binaries/<platform>/``, through no link."""
    from types import SimpleNamespace

    import fmpy

    from wmr.adapters.fmi.slave import checked_library
    from wmr.infra.errors import FmuError

    md = SimpleNamespace(fmiVersion="3.0", coSimulation=SimpleNamespace(modelIdentifier="m"))
    name = "m" + fmpy.sharedLibraryExtension
    folder = tmp_path / "fmu"
    with pytest.raises(FmuError, match="has no binary for this platform"):
        checked_library(folder, md, "x.fmu")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / name).write_bytes(b"")
    (folder / "binaries").mkdir(parents=True)
    (folder / "binaries" / fmpy.platform_tuple).symlink_to(tmp_path / "elsewhere")
    with pytest.raises(FmuError, match=f"x.fmu: binaries/{fmpy.platform_tuple} is a "
                                       "symbolic link: refused"):
        checked_library(folder, md, "x.fmu")
    (folder / "binaries" / fmpy.platform_tuple).unlink()
    (folder / "binaries" / fmpy.platform_tuple / name).mkdir(parents=True)
    with pytest.raises(FmuError, match="is not a regular file"):
        checked_library(folder, md, "x.fmu")
    (folder / "binaries" / fmpy.platform_tuple / name).rmdir()
    (folder / "binaries" / fmpy.platform_tuple / name).write_bytes(b"")
    assert checked_library(folder, md, "x.fmu") == folder / "binaries" / \
        fmpy.platform_tuple / name
    md.coSimulation.modelIdentifier = "a" * 201
    with pytest.raises(FmuError, match="at most 200 characters"):
        checked_library(folder, md, "x.fmu")


if __name__ == "__main__":  # python tests/test_hostile_archives.py GOOD.ssp OUT_DIR
    good_path, out_dir = Path(sys.argv[1]), Path(sys.argv[2])
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "outside").mkdir(exist_ok=True)
    target = out_dir / "outside" / "existing.txt"
    target.write_bytes(b"precious")
    for name, (make, _) in CASES.items():
        make(good_path, out_dir / f"{name}.ssp", target, out_dir, True)
        print(out_dir / f"{name}.ssp")


def test_a_model_description_over_16_mib_is_refused_before_it_is_parsed(tmp_path: Path) -> None:
    """Issue 28 item 7: a 2.5 MB FMU with a 62.5 MiB model description, under the old 64 MiB
    limit, made fmpy's parse peak at 1.54 GB before it was refused; the limit is now 16 MiB
    (real ones reach about 10 MB), checked as the member streams (a 20 MiB one here)."""
    from wmr.adapters.fmi.archive import open_archive
    from wmr.infra.errors import FmuError

    fmu = write_zip(tmp_path / "big.fmu", [spaces_bomb(
        "modelDescription.xml", b'<?xml version="1.0"?>\n<fmiModelDescription>', 20,
        b"</fmiModelDescription>\n")])
    with open_archive(fmu, "test") as archive, pytest.raises(
            FmuError, match=f"modelDescription.xml' unpacks to more than {16 * MiB} bytes"):
        archive.check()

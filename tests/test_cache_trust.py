"""Nothing is loaded that was not checked (issue 28): a cache entry (the C stepper, the built
FMUs, pymoca's parser cache) is used only if this user owns it and no one else can write it or
a folder above it up to the cache's root; the stale-folder cleaner touches only folders of
ours.  Run as root: other users are made with ``os.chown``."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

#: A user id nobody on the test machine has: "another local user".
OTHER_UID = 54321

#: A library whose constructor writes a marker file: it says whether it was ever loaded.
MARKER_C = """#include <stdio.h>
__attribute__((constructor)) static void owned(void) {
    FILE *f = fopen("%s", "w");
    if (f) { fputs("owned", f); fclose(f); }
}
"""

needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="chown to another user needs root")


def _planted_library(path: Path, marker: Path) -> None:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    source = path.with_suffix(".c")
    source.write_text(MARKER_C % marker)
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(path), str(source)], check=True)
    source.unlink()


# ------------------------------------------------------------------ the stale-folder cleaner


@needs_root
def test_the_stale_folder_cleaner_follows_no_link_and_removes_only_our_folders(
        tmp_path: Path) -> None:
    """The cleaner opened ``wmr-fmu-*/.wmr-owner.lock`` read-write through any link, whoever
    owned the folder, then removed the folder: a planted link made root open and lock a
    root-only file.  Now: a link is not opened, another user's folder is left alone."""
    from wmr.adapters.fmi.slave import remove_stale_folders

    secret = tmp_path / "root-only.txt"
    secret.write_text("secret")
    secret.chmod(0o600)
    linked = tmp_path / "wmr-fmu-linked"
    linked.mkdir()
    (linked / ".wmr-owner.lock").symlink_to(secret)
    theirs = tmp_path / "wmr-fmu-theirs"
    theirs.mkdir()
    (theirs / ".wmr-owner.lock").write_text("")
    os.chown(theirs / ".wmr-owner.lock", OTHER_UID, OTHER_UID)
    os.chown(theirs, OTHER_UID, OTHER_UID)
    planted_file = tmp_path / "wmr-fmu-file"
    planted_file.mkdir()
    (planted_file / ".wmr-owner.lock").write_text("")
    os.chown(planted_file / ".wmr-owner.lock", OTHER_UID, OTHER_UID)
    dir_link = tmp_path / "wmr-fmu-dirlink"
    dir_link.symlink_to(theirs)
    ours = tmp_path / "wmr-fmu-ours"  # a killed run's folder: removed as before
    ours.mkdir()
    (ours / ".wmr-owner.lock").write_text("")

    assert remove_stale_folders(tmp_path) == [ours]
    assert linked.is_dir() and theirs.is_dir() and planted_file.is_dir() and dir_link.exists()
    assert secret.read_text() == "secret" and not ours.exists()


# ------------------------------------------------------------------ the C stepper


@pytest.fixture
def fresh_stepper(monkeypatch: pytest.MonkeyPatch) -> None:
    """``load_stepper`` builds and loads again in this test (its library is kept per process)."""
    from wmr.adapters import stepper

    monkeypatch.setattr(stepper, "_STEPPER", [])
    monkeypatch.delenv("WMR_STEPPER", raising=False)


def _umask_000_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A cache made by a first ``build_stepper`` under ``umask 000``: its real library."""
    from wmr.build.fmus import build_stepper

    monkeypatch.setenv("WMR_CACHE_DIR", str(tmp_path / "cache"))
    old = os.umask(0)
    try:
        lib = build_stepper()
    finally:
        os.umask(old)
    if lib is None:
        pytest.skip("no C compiler")
    return lib


def test_cache_folders_are_made_0700_whatever_the_umask(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Under ``umask 000`` the cache folders were made 0777: anyone could plant a library."""
    lib = _umask_000_cache(tmp_path, monkeypatch)
    for folder in (tmp_path / "cache", lib.parent):
        assert folder.stat().st_mode & 0o777 == 0o700, folder


@needs_root
@pytest.mark.parametrize("case", ["folder-0777", "folder-of-another-user",
                                  "cache-root-of-another-user"])
def test_a_stepper_planted_in_a_cache_others_can_write_is_never_loaded(
        case: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fresh_stepper: None,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A library planted at ``wmr_stepper-<hash>.so`` in a folder someone else can write (or
    owns) was dlopened by the next run (its constructor ran, the missing symbol's
    AttributeError was swallowed, the run went on): now refused in one line, never loaded,
    and the run takes the pure-Python path (the same bits)."""
    from wmr.adapters import stepper

    lib = _umask_000_cache(tmp_path, monkeypatch)
    marker = tmp_path / "marker.txt"
    _planted_library(lib, marker)
    if case == "folder-0777":
        lib.parent.chmod(0o777)
        bad = lib.parent
    elif case == "folder-of-another-user":
        os.chown(lib.parent, OTHER_UID, OTHER_UID)
        bad = lib.parent
    else:
        os.chown(tmp_path / "cache", OTHER_UID, OTHER_UID)
        bad = tmp_path / "cache"
    assert stepper.load_stepper() is None
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{bad}: is " in err[0] and "WMR_CACHE_DIR" in err[0], err
    assert err[0].startswith("wmr: warning: the C stepper is not used"), err
    assert not marker.exists(), "the planted library was loaded"


@needs_root
@pytest.mark.parametrize("case", ["library-of-another-user", "library-0666", "symlink"])
def test_a_planted_stepper_in_our_own_folder_is_built_again_not_loaded(
        case: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fresh_stepper: None,
        capsys: pytest.CaptureFixture[str]) -> None:
    """In a folder only we can write, a library others could have written (another owner,
    mode 0666, a link) is compiled again over, said in one line, and the new one is loaded."""
    from wmr.adapters import stepper

    lib = _umask_000_cache(tmp_path, monkeypatch)
    marker = tmp_path / "marker.txt"
    if case == "symlink":
        _planted_library(tmp_path / "elsewhere.so", marker)
        lib.unlink()
        lib.symlink_to(tmp_path / "elsewhere.so")
    else:
        _planted_library(lib, marker)
        if case == "library-of-another-user":
            os.chown(lib, OTHER_UID, OTHER_UID)
        else:
            lib.chmod(0o666)
    loaded = stepper.load_stepper()
    assert loaded is not None and loaded.wmr_exchange is not None
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{lib}: is " in err[0] and "compiling the C stepper again" \
        in err[0], err
    assert not marker.exists(), "the planted library was loaded"
    st = os.lstat(lib)
    assert st.st_uid == os.geteuid() and st.st_mode & 0o022 == 0 and not lib.is_symlink()


def test_a_stepper_without_its_functions_is_said_not_silently_skipped(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fresh_stepper: None,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A (trusted) library that lacks a function was dropped silently (the AttributeError
    swallowed): now one warning line naming it."""
    import wmr.build.fmus
    from wmr.adapters import stepper

    empty = tmp_path / "empty.so"
    _planted_library(empty, tmp_path / "marker.txt")
    monkeypatch.setattr(wmr.build.fmus, "build_stepper", lambda *a, **k: empty)
    assert stepper.load_stepper() is None
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(empty) in err[0] and "wmr_exchange" in err[0], err


# ------------------------------------------------------------------ the FMU build cache


def _hand_made_build(out: Path, digest: str) -> dict[str, Path]:
    """A build folder made here: every product (a few bytes) and the stamp of the build."""
    import hashlib
    import json

    from wmr.build import fmus as fmus_module

    products = fmus_module._products(out)
    out.mkdir(parents=True)
    for key, path in products.items():
        path.write_bytes(f"product {key}".encode())
    (out / fmus_module._STAMP).write_text(json.dumps({
        "digest": digest,
        "sha256": {k: hashlib.sha256(p.read_bytes()).hexdigest() for k, p in products.items()}}))
    return products


@needs_root
@pytest.mark.parametrize("case", ["fmu-of-another-user", "stamp-0666", "fmu-symlink"])
def test_fmus_others_could_have_written_are_not_reused(
        case: str, tmp_path: Path) -> None:
    """``_reusable`` trusted any stamp whose hashes matched: a planted FMU with a recomputed
    stamp was reused.  Now a product or stamp others could have written is built again, said
    in one line."""
    from wmr.build import fmus as fmus_module

    digest = "d" * 64
    out = tmp_path / "out"
    products = _hand_made_build(out, digest)
    said: list[str] = []
    assert fmus_module._reusable(out, digest, said.append) == products  # trusted: reused
    assert said == []
    target = products["2"]
    if case == "fmu-of-another-user":
        os.chown(target, OTHER_UID, OTHER_UID)
    elif case == "stamp-0666":
        target = out / fmus_module._STAMP
        target.chmod(0o666)
    else:
        (tmp_path / "planted.fmu").write_bytes(target.read_bytes())
        target.unlink()
        target.symlink_to(tmp_path / "planted.fmu")
    assert fmus_module._reusable(out, digest, said.append) is None
    assert len(said) == 1 and said[0].startswith(f"{target}: is ") and \
        "building the FMUs again" in said[0], said


@needs_root
@pytest.mark.parametrize("case", ["0777", "another-user"])
def test_a_build_folder_others_can_write_is_refused_in_one_line(
        case: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A complete, stamped build in a folder others can write was reused as is (planted FMUs
    with a recomputed stamp loaded by the next run): now refused, naming the folder and
    ``WMR_CACHE_DIR``."""
    from wmr.build import fmus as fmus_module
    from wmr.infra.errors import ConfigError

    monkeypatch.setenv("WMR_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(fmus_module, "build_digest", lambda *a, **k: "d" * 64)
    monkeypatch.setattr(fmus_module, "build_stepper", lambda *a, **k: None)
    out = fmus_module.default_out_dir("host")
    _hand_made_build(out, "d" * 64)
    if case == "0777":
        out.chmod(0o777)
    else:
        os.chown(out, OTHER_UID, OTHER_UID)
    with pytest.raises(ConfigError, match=f"^WMR_CACHE_DIR: {out}: is .* wmr loads libraries "
                                          "from the FMU folder"):
        fmus_module.build_fmus(platforms="host", cc="gcc")


def test_a_read_only_cache_names_wmr_cache_dir(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A cache whose build lock cannot be made (a read-only HOME) named the lock, not the
    way out: now the line names ``WMR_CACHE_DIR``."""
    import errno

    from wmr.build import fmus as fmus_module
    from wmr.infra.errors import ConfigError, LogError

    monkeypatch.setenv("WMR_CACHE_DIR", str(tmp_path / "cache"))

    def read_only(path: Path, *args: object) -> int:
        raise LogError(f"{path}: cannot create the build lock: "
                       f"{os.strerror(errno.EROFS)}")

    monkeypatch.setattr(fmus_module, "open_own", read_only)
    with pytest.raises(ConfigError, match="^WMR_CACHE_DIR: .*Read-only file system "
                                          r"\(set WMR_CACHE_DIR to a folder"):
        with fmus_module._locked(fmus_module.default_out_dir("host")):
            pass


def test_a_full_disk_in_a_build_names_the_file(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """``wmr fmu build`` on a full disk said ``No space left on device`` and no path."""
    import errno

    from wmr.build import fmus as fmus_module
    from wmr.infra.errors import DiskFullError

    target = tmp_path / "out" / "wmr_robot-fmi2.fmu"

    def full(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target))

    monkeypatch.setattr(fmus_module, "build_digest", lambda *a, **k: "d" * 64)
    monkeypatch.setattr(fmus_module, "_build", full)
    with pytest.raises(DiskFullError, match=f"no space left on .* while writing {target}$"):
        fmus_module.build_fmus(tmp_path / "out", platforms="host", cc="gcc")


# ------------------------------------------------------------------ pymoca's parser cache


class _Command:
    """A pickle that runs a shell command when it is unpickled."""

    def __init__(self, command: str) -> None:
        self.command = command

    def __reduce__(self) -> tuple[object, tuple[str]]:
        return os.system, (self.command,)


def test_a_planted_pymoca_pickle_is_never_unpickled_on_the_build_path(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """pymoca's parser cache (``$XDG_CACHE_HOME/pymoca/model_txt_cache.db``) keeps parsed
    files as pickles, keyed by a hash of the text: a row planted for our Modelica sources ran
    a command as whoever built.  The build path parses with the cache off."""
    import pickle
    import sqlite3

    import pymoca.parser

    from wmr.build.flatten import flatten
    from wmr.infra import paths

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    folder = tmp_path / "xdg" / "pymoca"
    folder.mkdir(parents=True)
    sources = sorted(paths.modelica_dir().rglob("*.mo"))
    for source in sources:  # pymoca's own rows for our sources, then made hostile
        pymoca.parser.parse_text(source.read_text(encoding="utf-8"), model_cache_folder=folder)
    marker = tmp_path / "marker.txt"
    db = sqlite3.connect(folder / pymoca.parser.DEFAULT_MODEL_CACHE_DB)
    with db:
        db.execute("UPDATE models SET data = ?",
                   (pickle.dumps(_Command(f"touch {marker}")),))
        assert db.execute("SELECT COUNT(*) FROM models").fetchone()[0] == len(sources)
    db.close()
    try:
        model = flatten(paths.modelica_dir())
    finally:  # before: os.system ran, and its 0 was taken for a parsed file
        assert not marker.exists(), "the planted pickle was unpickled"
    assert model.parameters  # the model was parsed from its source
    assert pymoca.parser.parse_text.__name__ == "parse_text" and \
        pymoca.parser.parse_text.__module__ == "pymoca.parser"  # pymoca left as it was


def test_untrusted_names_the_first_part_that_fails(tmp_path: Path) -> None:
    """``infra.trust.untrusted`` directly: a file in our 0700 folder may be used; the same file
    in a folder others can write, behind a link, or outside the root may not, and the line
    names that part. Seen failing with the group/other write check dropped."""
    from wmr.infra.trust import untrusted

    root = tmp_path / "cache"
    root.mkdir(mode=0o700)
    os.chmod(tmp_path, 0o700)
    (root / "sub").mkdir(mode=0o700)
    lib = root / "sub" / "lib.so"
    lib.write_bytes(b"x")
    os.chmod(lib, 0o600)
    assert untrusted(lib, root) is None
    assert untrusted(root / "sub" / "not-yet.so", root) is None  # nothing there to use
    os.chmod(root / "sub", 0o777)
    assert untrusted(lib, root) == f"{root / 'sub'}: is writable by other users (mode 777)"
    os.chmod(root / "sub", 0o700)
    (root / "link.so").symlink_to(lib)
    assert untrusted(root / "link.so", root) == f"{root / 'link.so'}: is a symbolic link"
    assert untrusted(tmp_path / "elsewhere.so", root) == \
        f"{tmp_path / 'elsewhere.so'}: is not inside {root}"

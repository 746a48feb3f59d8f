"""``wmr fmu build`` rebuilds when an input changed (issue 23, gap 3): the changed direction of
"a build is skipped when a digest over every input matches" (the unchanged direction is
``test_fmu_build.test_rebuild_is_skipped_when_nothing_changed``).

The model is changed for real (a parameter default in a ``.mo`` file of a copy of the Modelica
sources); the build itself is stopped where it would start, so the test costs no compile and
leaves the session's FMUs as they are.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

import wmr.build.fmus as fmus_module
from wmr.build.fmus import BuildResult, build_fmus
from wmr.infra import paths


class _WouldBuild(Exception):
    pass


def _stop_before_compiling(*args: object, **kwargs: object) -> dict[int, Path]:
    raise _WouldBuild


@pytest.fixture
def model_copy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the Modelica sources that the build reads instead of the project's."""
    src = tmp_path / "modelica"
    shutil.copytree(paths.modelica_dir(), src)
    monkeypatch.setattr(paths, "modelica_dir", lambda: src)
    monkeypatch.setattr(fmus_module, "_build", _stop_before_compiling)
    return src


@pytest.mark.parametrize(("file", "old", "new"), [
    ("WMR/Platform.mo", 'min = 0) = 25 "Mass', 'min = 0) = 26 "Mass'),  # a parameter's default
    ("WMR/Robot.mo", "parameter Real Iwm", "parameter Real  Iwm"),  # any byte of the source
])
def test_a_changed_model_source_is_rebuilt_and_the_unchanged_copy_reused(
        built: BuildResult, fmu_dir: Path, model_copy: Path, file: str, old: str,
        new: str) -> None:
    assert build_fmus(fmu_dir).reused, "the copy of the unchanged sources is the same input"
    mo = model_copy / file
    text = mo.read_text()
    assert text.count(old) == 1
    mo.write_text(text.replace(old, new))
    notices: list[str] = []
    with pytest.raises(_WouldBuild):
        build_fmus(fmu_dir, on_build=notices.append)
    assert len(notices) == 1 and "building" in notices[0]
    assert fmus_module.build_digest() != built.digest
    mo.write_text(text)  # changed back: the FMUs there are the ones again
    assert build_fmus(fmu_dir).reused


def test_another_compiler_or_other_platforms_is_a_rebuild() -> None:
    """Another compiler version, or another set of platforms, is another build input."""
    from wmr.build.platforms import PLATFORMS, Compiler

    zig_a = Compiler(("zig", "cc"), "zig 0.13.0", True)
    zig_b = Compiler(("zig", "cc"), "zig 0.14.0", True)
    assert fmus_module.build_digest(zig_a, PLATFORMS) != fmus_module.build_digest(zig_b, PLATFORMS)
    assert fmus_module.build_digest(zig_a, PLATFORMS[:1]) != fmus_module.build_digest(
        zig_a, PLATFORMS[1:2])
    assert fmus_module.build_digest(zig_a, PLATFORMS) == fmus_module.build_digest(
        zig_a, PLATFORMS)


def test_a_stamp_without_the_products_hashes_is_rebuilt_not_a_crash(
        built: BuildResult, fmu_dir: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "fmus"
    shutil.copytree(fmu_dir, out, ignore=shutil.ignore_patterns(".wmr-build.lock"))
    assert build_fmus(out).reused  # the copy, stamp and all, is the same build
    stamp = out / fmus_module._STAMP
    recorded = json.loads(stamp.read_text())
    del recorded["sha256"]  # a stamp of an older build, or cut by hand
    stamp.write_text(json.dumps(recorded))
    monkeypatch.setattr(fmus_module, "_build", _stop_before_compiling)
    with pytest.raises(_WouldBuild):
        build_fmus(out)


def test_a_changed_build_module_is_a_rebuild(tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """The code generator is a build input (docs/fmu.md: a digest over every input): a byte
    changed in any module of ``wmr/build`` (here in a copy the digest is pointed at) changes
    the digest; a file that is not a Python module does not."""
    from wmr.build.platforms import PLATFORMS, Compiler

    zig = Compiler(("zig", "cc"), "zig 0.13.0", True)
    build = tmp_path / "build"
    shutil.copytree(Path(fmus_module.__file__).parent, build,
                    ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(fmus_module, "__file__", str(build / "fmus.py"))
    before = fmus_module.build_digest(zig, PLATFORMS)
    (build / "notes.txt").write_text("not a module")
    assert fmus_module.build_digest(zig, PLATFORMS) == before
    codegen = build / "codegen.py"
    codegen.write_bytes(codegen.read_bytes() + b"\n")
    assert fmus_module.build_digest(zig, PLATFORMS) != before


def test_another_target_is_a_rebuild_of_a_cross_build_not_of_a_host_build() -> None:
    """zig builds each platform for its ``zig_target`` (a glibc version in it, say): another
    target under the same platform name is another build; a host compiler builds for the host
    whatever the target says, so the target changes nothing (no needless rebuild)."""
    import dataclasses

    from wmr.build.platforms import PLATFORMS, Compiler

    zig = Compiler(("zig", "cc"), "zig 0.13.0", True)
    gcc = Compiler(("gcc",), "gcc 13.2.0", False)
    first = PLATFORMS[0]
    other = (dataclasses.replace(first, zig_target=first.zig_target + ".2.17"), *PLATFORMS[1:])
    assert fmus_module.build_digest(zig, other) != fmus_module.build_digest(zig, PLATFORMS)
    assert fmus_module.build_digest(gcc, other[:1]) == fmus_module.build_digest(gcc, PLATFORMS[:1])


def _hand_made_build(out: Path, digest: str) -> dict[str, Path]:
    """A build folder made here: every product (a few bytes each) and the stamp of the build,
    with the product hashes computed here."""
    import hashlib

    products = fmus_module._products(out)
    out.mkdir()
    for key, path in products.items():
        path.write_bytes(f"product {key}".encode())
    (out / fmus_module._STAMP).write_text(json.dumps({
        "digest": digest,
        "sha256": {k: hashlib.sha256(p.read_bytes()).hexdigest() for k, p in products.items()}}))
    return products


def test_a_build_is_reused_while_its_stamp_and_products_hold_else_rebuilt(tmp_path: Path) -> None:
    """docs/fmu.md: a build is skipped when the digest over every input matches the stamp
    and every product is the one built; anything else is a rebuild (``None``), not a crash."""
    digest = "d" * 64
    products = _hand_made_build(tmp_path / "ok", digest)
    assert fmus_module._reusable(tmp_path / "ok", digest) == products
    assert fmus_module._reusable(tmp_path / "ok", "e" * 64) is None
    for key in products:
        for damage in ("changed", "missing", "unhashed"):
            out = tmp_path / f"{damage}-{key}"
            made = _hand_made_build(out, digest)
            if damage == "changed":
                made[key].write_bytes(made[key].read_bytes() + b"!")
            elif damage == "missing":
                made[key].unlink()
            else:
                stamp = out / fmus_module._STAMP
                recorded = json.loads(stamp.read_text())
                del recorded["sha256"][key]
                stamp.write_text(json.dumps(recorded))
            assert fmus_module._reusable(out, digest) is None, (damage, key)
    for stamp_text in (None, "{not json", json.dumps({"sha256": {}})):
        out = tmp_path / f"stamp-{len(stamp_text or '')}"
        _hand_made_build(out, digest)
        if stamp_text is None:
            (out / fmus_module._STAMP).unlink()
        else:
            (out / fmus_module._STAMP).write_text(stamp_text)
        assert fmus_module._reusable(out, digest) is None, stamp_text

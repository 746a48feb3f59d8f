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

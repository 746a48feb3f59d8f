"""Issue 11, defects 4, 5 and 10: nonsense refused with a reason, output paths checked before
any work, a JSON line on stdout for input errors under --json, and the small things."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from wmr.cli import main
from wmr.config.naming import plural
from wmr.infra.errors import ConfigError
from wmr.infra.paths import _REPO_ROOT

SHORT = '''name = "short"
start = [0.0, 0.0, 0.0]
goal = [1.5, 0.0, 0.0]
max_time_s = 20.0
'''


def _one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("wmr: error:"), err
    return err[0]


@pytest.mark.parametrize(("args", "field", "reason"), [
    (["run", "--param", "m=0"], "params.m", "without mass"),
    (["run", "--param", "Ig=0", "--param", "l=0", "--param", "Iwm=0"], "params.Ig", "singular"),
    (["run", "--param", "m=0.5"], "control_period_s", "wheel inertia"),
    (["run", "--period", "100"], "control_period_s", "wheel servos"),
    (["run", "--period", "0.1"], "control_period_s", "K_pw h / J"),
    (["run", "--stop-radius", "1000"], "--stop-radius", "converged where it stands"),
    (["batch", "fig9", "--run-timeout", "-1"], "--run-timeout", ">= 0"),
    (["batch", "fig9", "--workers", "0"], "--workers", ">= 1"),
    (["batch", "fig9", "--scheduler", "garbage://x:1"], "--scheduler", "unknown scheme"),
    (["batch", "fig9", "--scheduler", "nohostport"], "--scheduler", "HOST:PORT"),
    (["batch", "fig9", "--scheduler", "tcp://127.0.0.1:1"], "--scheduler", "no scheduler"),
    (["report", ".", "--max-plots", "-1"], "--max-plots", ">= 0"),
])
def test_nonsense_is_refused_with_a_reason_before_any_work(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        args: list[str], field: str, reason: str) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(args) == 1
    line = _one_error_line(capsys)
    assert field in line and reason in line
    assert list(tmp_path.iterdir()) == []  # no log, no batch folder


def test_the_sanity_limits_sit_where_the_physics_says() -> None:
    from wmr.core.plant import Pose
    from wmr.core.runspec import RunSpec

    RunSpec("a", Pose(0, 0, 0), Pose(10, 0, 0), period_s=0.08)  # K_pw h / J = 1.92
    with pytest.raises(ConfigError, match="control_period_s"):
        RunSpec("a", Pose(0, 0, 0), Pose(10, 0, 0), period_s=0.084)  # 2.02
    RunSpec("a", Pose(0, 0, 0), Pose(10, 0, 0), stop_radius_m=9.9)
    RunSpec("a", Pose(0, 0, 0), Pose(0.01, 0, 0))  # a start inside the default radius
    RunSpec("a", Pose(0, 0, 0), Pose(0, 0, 1.0), stop_radius_m=0.5)  # a turn on the spot


def _under_a_file(tmp_path: Path) -> Path:
    f = tmp_path / "README.md"
    f.write_text("a file\n")
    return f


@pytest.mark.parametrize(("args", "option", "heavy"), [
    (["run", "--out", "{f}/x.mcap"], "--out", "wmr.apps.run.run_to_log"),
    (["run", "--out", "{d}"], "--out", "wmr.apps.run.run_to_log"),
    (["optimal", "--out", "{f}/x.mcap"], "--out", "wmr.adapters.ocp.solve_optimal"),
    (["fmu", "build", "--out", "{f}/fmus"], "--out", "wmr.build.fmus.build_fmus"),
    (["figures", "--out", "{f}/figs"], "--out", "wmr.apps.figures.make_figures"),
    (["replay", "{d}", "--rrd", "{f}/x.rrd"], "--rrd", "wmr.adapters.rerun.replay.replay"),
    (["batch", "fig9", "--out", "{f}/b"], "--out", "wmr.apps.batch.run_batch"),
    (["benchmark", "--out", "{f}/b"], "--out", "wmr.apps.benchmark.run_benchmark"),
    (["tune", "--save", "{f}/t.json"], "--save", "wmr.apps.benchmark.run_optimal"),
    (["tune", "--budget", "0"], "--budget", "wmr.apps.benchmark.run_optimal"),
])
def test_output_paths_are_checked_before_any_work(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        args: list[str], option: str, heavy: str) -> None:
    module, _, name = heavy.rpartition(".")

    def never(*_a: object, **_k: object) -> None:
        raise AssertionError(f"{heavy} ran before the output path was checked")

    import importlib

    monkeypatch.setattr(importlib.import_module(module), name, never)
    f = _under_a_file(tmp_path)
    code = main([a.format(f=f, d=tmp_path) for a in args])
    line = _one_error_line(capsys)
    assert code == 1 and option in line, line  # 1: the user's error, not an internal one (2)


def test_json_prints_a_json_line_on_an_input_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--param", "m=0", "--json"]) == 1
    captured = capsys.readouterr()
    record = json.loads(captured.out.strip().splitlines()[-1])
    assert record["status"] == "error" and record["field"] == "params.m"
    assert "m" in record["message"] and captured.err.startswith("wmr: error:")


def test_too_many_workers_is_a_warning(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    assert main(["batch", str(tmp_path / "missing.toml"), "--workers", "64"]) == 1
    err = capsys.readouterr().err
    assert "wmr: warning: --workers 64 on 2 cores" in err


def test_counts_are_plural_only_when_they_should_be() -> None:
    assert [plural(n, "run") for n in (0, 1, 2)] == ["0 runs", "1 run", "2 runs"]


def test_view_says_where_the_recording_went(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "v.mcap"
    main(["run", "--max-time", "0.5", "--view", "--out", str(out)])
    err = capsys.readouterr().err
    assert f"live view recorded in {out.with_suffix('.rrd')}" in err
    assert out.with_suffix(".rrd").is_file()


def test_tune_without_the_optimum_prints_no_nan(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    spec = tmp_path / "short.toml"
    spec.write_text(SHORT)
    assert main(["tune", str(spec), "--no-optimal", "--budget", "1"]) == 0
    out = capsys.readouterr().out
    assert "short" in out and "nan" not in out.lower() and "ratio" not in out


def test_default_outputs_are_ignored_by_git() -> None:
    paths = ["runs/fig11.mcap", "batches/fig9/summary.csv", "figures/fig9.png"]
    try:
        done = subprocess.run(["git", "check-ignore", *paths], cwd=_REPO_ROOT,
                              capture_output=True, text=True, check=False)
    except FileNotFoundError:
        pytest.skip("no git")
    if done.returncode == 128:
        pytest.skip("not a git checkout")
    assert done.stdout.split() == paths


@pytest.mark.parametrize(("text", "field", "words"), [
    ('name = "d"\nstart = [0.0, 0.0, 0.0]\n[[runs]]\nname = "a"\ngoal = [1.0, 0.0, 0.0]\n'
     '[[runs]]\nname = "a"\ngoal = [2.0, 0.0, 0.0]\n', "runs[1].name", "already the name"),
    ('name = "g"\nstart = [0.0, 0.0, 0.0]\ngoal = [1.0, 0.0, 0.0]\n[grid]\n"gains.K_ps" = '
     '[0.4, 0.5]\n', "grid", "wmr batch"),
])
def test_scenario_mistakes_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                     text: str, field: str, words: str) -> None:
    path = tmp_path / "s.toml"
    path.write_text(text)
    assert main(["run", str(path), "--out", str(tmp_path / "x.mcap")]) == 1
    line = _one_error_line(capsys)
    assert f"error: {field}:" in line and words in line


def test_a_missing_random_seed_is_missing() -> None:
    from wmr.apps.batch import parse_batch

    with pytest.raises(ConfigError, match=r"random\.seed: missing"):
        parse_batch({"name": "r", "start": [0.0, 0.0, 0.0], "goal": [1.0, 0.0, 0.0],
                     "random": {"n": 2, "gains": {"K_ps": {"dist": "uniform", "low": 0.4,
                                                           "high": 0.6}}}})


def test_an_error_line_names_a_long_path_whole_and_cuts_a_hostile_field() -> None:
    """A path as an error's field was cut at 80 characters ("/tmp/... (94 characters) ...")
    where CI's temporary folders made it longer; a key of thousands of characters is still
    cut, and the line stays within MAX_LINE_CHARS."""
    from wmr.cli import MAX_LINE_CHARS, error_line

    path = "/tmp/pytest-of-root/pytest-0/popen-gw1/" + "a-long-test-name_0/" * 6 + "wmr.fmu"
    assert 120 < len(path) < 300
    assert error_line(ConfigError(path, "is a named pipe (FIFO)")).startswith(f"{path}: is a")
    line = error_line(ConfigError("k" * 5000, "unknown field"))
    assert "characters) ..." in line and len(line) <= MAX_LINE_CHARS


def test_a_scenarios_own_value_is_named_by_its_key_an_options_by_the_option(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The same stop radius from a scenario file is the file's key ``stop_radius_m``; given
    with ``--stop-radius`` it is that option (the command line names what the user typed).
    Seen failing with every request field named by its option."""
    far = tmp_path / "far.toml"
    far.write_text('name = "far"\nstart = [0, 0, 0]\ngoal = [20, 10, 0]\nstop_radius_m = 1000\n')
    assert main(["run", str(far), "--out", str(tmp_path / "o.mcap")]) == 1
    assert _one_error_line(capsys).startswith("wmr: error: stop_radius_m: 1000 m reaches")
    assert main(["run", "--stop-radius", "1000", "--out", str(tmp_path / "o.mcap")]) == 1
    assert _one_error_line(capsys).startswith("wmr: error: --stop-radius: 1000 m reaches")

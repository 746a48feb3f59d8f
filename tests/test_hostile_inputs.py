"""Inputs from strangers (issue 17, part C): parameters, names, journals and FMUs that used to
end in an internal error, a crash or a silently wrong summary.  Each refusal is one line that
names the field or the file."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tomllib
import zipfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest

from wmr.adapters.mcap import read_run
from wmr.apps.batch import BatchOptions, load_batch, parse_batch, run_batch
from wmr.cli import MAX_LINE_CHARS, main
from wmr.config.naming import default_log_path, file_stem
from wmr.config.scenario import Overrides, load_scenario, parse_scenario, with_overrides
from wmr.infra.errors import ConfigError, WmrError

FIG11 = 'name = "h"\nstart = [0.0, 0.0, 0.0]\ngoal = [2.0, 1.0, 0.0]\n'


# -- item 9: a length of 1e308 overflows the mass matrix ------------------------------------------

@pytest.mark.parametrize("name", ["r", "L", "l"])
@pytest.mark.parametrize("route", ["flag", "file", "grid", "random"])
def test_a_huge_length_is_a_config_error_by_every_route(name: str, route: str) -> None:
    """``params.r = 1e308`` used to raise OverflowError from ``r**2`` in the mass matrix."""
    with pytest.raises(ConfigError) as err:
        if route == "flag":
            with_overrides(load_scenario("fig11").runs[0], Overrides(params={name: 1e308}))
        elif route == "file":
            parse_scenario(tomllib.loads(FIG11 + f"[params]\n{name} = 1e308\n"))
        elif route == "grid":
            parse_batch(tomllib.loads(FIG11 + f"[grid.params]\n{name} = [0.2, 1e308]\n"))
        else:
            batch = parse_batch(tomllib.loads(
                FIG11 + f"[random]\nseed = 1\nn = 3\n[random.params]\n{name} = "
                '{ dist = "uniform", low = 1e307, high = 1e308 }\n'))
            list(batch.runs)
    assert f"params.{name}" in str(err.value) and "overflow" in str(err.value)


def test_products_that_overflow_name_the_extreme_parameter() -> None:
    """Each value finite and its square too, but m l^2 is not."""
    with pytest.raises(ConfigError) as err:
        with_overrides(load_scenario("fig11").runs[0], Overrides(params={"m": 1e300, "l": 1e10}))
    assert err.value.field == "params.m"


# -- item 9: run names whose file name is too long once percent-encoded ---------------------------

@pytest.mark.parametrize("name", ["é" * 60, "🤖" * 70, "a" * 119 + "é" * 60, "." + "\u202e" * 90])
def test_a_long_run_name_gives_a_file_name_every_file_system_takes(name: str,
                                                                    tmp_path: Path) -> None:
    """The 120-character cap counted characters; ``é`` is 6 bytes once written ``%C3%A9``."""
    path = default_log_path(name, tmp_path)
    assert len(path.name.encode()) + len(".partial.recovering") <= 255
    path.with_name(path.name + ".partial.recovering").touch()  # the longest sibling
    assert default_log_path(name[:-1] + "x", tmp_path) != path  # long names stay apart
    assert "%" not in path.name[-16:]  # cut at a character, not inside its escapes
    assert file_stem("fig11-m=40") == "fig11-m=40"  # short names unchanged


LONG_NAMES = ["é" * 60, "🤖" * 70, "a" * 300, "." + "\u202e" * 90, "a.b" * 100]


@pytest.mark.parametrize("name", LONG_NAMES, ids=["e-acute", "emoji", "ascii", "bidi", "dots"])
def test_every_file_named_after_a_run_fits_the_file_system(name: str, tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    """``safe_filename`` had no cap: the default ``.rrd`` of a live view, the scenario a log
    attaches, ``wmr ssp export``'s ``NAME.ssp`` and the figures' logs were ``File name too
    long`` for these names.  One function cuts them all, by bytes after encoding."""
    from wmr.adapters.rerun.live_view import live_view_sink
    from wmr.apps.run import scenario_attachment_name
    from wmr.infra.paths import MAX_STEM_BYTES, safe_filename

    stem = safe_filename(name)
    assert len(stem.encode()) <= MAX_STEM_BYTES and stem == file_stem(name)
    for suffix in (".ssp", ".toml", ".rrd", ".mcap.partial.recovering"):
        (tmp_path / f"{stem}{suffix}").touch()  # the file system takes each
    assert safe_filename(name[:-1] + "x") != stem  # long names stay apart
    assert safe_filename(stem) != stem  # a cut stem is no other name's whole stem
    spec = load_scenario("fig11").runs[0]
    assert scenario_attachment_name(replace(spec, name=name)) == f"{stem}.toml"
    monkeypatch.chdir(tmp_path)
    live_view_sink(name, (1.0, 2.0, 0.5), None, spawn=False).close()
    assert (tmp_path / "runs" / f"{stem}.rrd").is_file()


def test_a_cut_stem_keeps_the_characters_it_keeps_whole() -> None:
    """Only the characters a cut leaves out change: a dot inside the name stays a dot."""
    from wmr.infra.paths import safe_filename

    assert safe_filename("a.b" * 100).startswith("a.ba.b")
    assert safe_filename(".x") == "%2Ex" and safe_filename("x~y") == "x%7Ey"


def test_wmr_run_of_a_scenario_named_in_emoji_writes_its_log(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    scenario = tmp_path / "emoji.toml"
    scenario.write_text(f'name = "{"🤖" * 70}"\nstart = [0.0, 0.0, 0.0]\n'
                        'goal = [1.0, 0.0, 0.0]\nmax_time_s = 0.05\n', encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scenario), "--json"]) == 3  # timeout: it ran
    record = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert Path(record["mcap"]).is_file() and record["name"] == "🤖" * 70


# -- item 10: error lines echo what they were given, cut and escaped -------------------------------

@pytest.mark.parametrize("argv", [
    ["run", "--param", "k" * 100_000 + "=1"],
    ["run", "--param", "\x1b[31mred\x1b[0m=1"],
    ["run", "--gain", "K_ps=\x1b[2J" + "9" * 5000],
    ["run", "--start", "1", "2", "\x1b]0;owned\x07" + "k" * 5000],  # argparse's own error
    ["run", "--out", "x" * 300 + ".mcap", "--max-time", "0.05"],  # too long for the disk
], ids=["long-key", "esc-key", "esc-value", "argparse", "name-too-long"])
def test_an_error_line_is_one_short_line_without_control_characters(
        argv: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = int(str(exc.code))
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code in (1, 2) and err.startswith(("wmr: error:", "wmr run: error:"))
    assert "internal error" not in err
    assert len(err) <= MAX_LINE_CHARS + 50
    assert not any(ord(c) < 32 or 0x7F <= ord(c) <= 0x9F for c in err)
    if "\x1b" in "".join(argv):
        assert "\\x1b" in err  # escaped, still visible


@pytest.mark.parametrize("stop", ["1e300", "inf", "nan", "0"])
def test_ssp_run_refuses_a_stop_time_libcosim_cannot_buffer(
        stop: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--stop-time 1e300`` reached libcosim, whose buffer message did not name the option."""
    assert main(["ssp", "run", str(tmp_path / "loop.ssp"), "--stop-time", stop,
                 "--out", str(tmp_path / "x.mcap")]) == 1
    assert capsys.readouterr().err.startswith("wmr: error: --stop-time: must be > 0 and at most")


# -- item 5: an FMU that returns fmi2Fatal is never called again -----------------------------------

_OUTPUTS = ("x", "y", "theta", "v", "omega", "omega_r", "omega_l")


def _fatal_robot(folder: Path, source: str = "fatal_robot.c",
                 defines: tuple[str, ...] = ()) -> Path:
    """``tests/other_fmus/fatal_robot.c`` (or ``source`` there, built with ``-D`` each of
    ``defines``) as an FMI 2.0 co-simulation FMU (skips without cc)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    root = folder / "fatal_robot"
    binary = root / "binaries" / "linux64" / "fatal_robot.so"
    binary.parent.mkdir(parents=True)
    subprocess.run([cc, "-shared", "-fPIC", "-O1", *(f"-D{d}" for d in defines), "-o",
                    str(binary), str(Path(__file__).parent / "other_fmus" / source), "-lm"],
                   check=True)
    names = [("tau_r", 'causality="input" variability="continuous"', '<Real start="0"/>'),
             ("tau_l", 'causality="input" variability="continuous"', '<Real start="0"/>')]
    names += [(n, 'causality="output" variability="continuous" initial="exact"',
               '<Real start="0"/>') for n in _OUTPUTS]
    names += [(n, 'causality="parameter" variability="fixed" initial="exact"',
               '<Real start="0"/>') for n in ("x0", "y0", "theta0")]
    variables = "\n".join(f'<ScalarVariable name="{n}" valueReference="{i}" {a}>{t}'
                          "</ScalarVariable>" for i, (n, a, t) in enumerate(names))
    outputs = "".join(f'<Unknown index="{i + 3}"/>' for i in range(len(_OUTPUTS)))
    (root / "modelDescription.xml").write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="2.0" '
        'modelName="fatal_robot" guid="{fatal-robot}" variableNamingConvention="flat">'
        '<CoSimulation modelIdentifier="fatal_robot"/><ModelVariables>'
        f"{variables}</ModelVariables><ModelStructure><Outputs>{outputs}</Outputs>"
        "</ModelStructure></fmiModelDescription>\n")
    fmu = folder / "fatal_robot.fmu"
    with zipfile.ZipFile(fmu, "w") as zf:
        for path in root.rglob("*"):
            if path.is_file():
                zf.write(path, path.relative_to(root).as_posix())
    return fmu


@pytest.mark.parametrize("variable,scale", [("tau_r", "5e-324"), ("tau_r", "1e-308"),
                                            ("x0", "5e-324")],
                         ids=["torque-5e-324", "torque-1e-308", "start-pose"])
def test_an_fmu_that_returned_fatal_is_left_alone_and_the_run_fails_cleanly(
        variable: str, scale: str, tmp_path: Path) -> None:
    """A map scale that makes an input inf (a torque while stepping, or the start pose while
    initialising): the FMU says fmi2Fatal, and used to be sent fmi2Terminate (forbidden after
    Fatal), which killed ``wmr run`` with SIGSEGV, exit 139, no JSON line.  Now: exit 1, the
    JSON line (or the text line), and a finished log of status failed."""
    fmu = _fatal_robot(tmp_path)
    unmapped = '", "'.join(("phi_r", "phi_l", "x_G", "y_G", "E_kin", "v0", "omega0", "m", "r",
                            "L", "l", "Ig", "Iwm", "b_f", "tau_c", "w_c"))
    (tmp_path / "map.toml").write_text(f'unmapped = ["{unmapped}"]\n[variables]\n'
                                       f'{variable} = {{ name = "{variable}", scale = {scale} }}\n')
    log = tmp_path / "run.mcap"
    argv = [sys.executable, "-m", "wmr.cli", "run", "--fmu", str(fmu), "--map",
            str(tmp_path / "map.toml"), "--out", str(log), "--start", "1", "0", "0"]
    for json_line in (True, False):
        proc = subprocess.run(argv + ["--json"] * json_line, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 1, proc.stderr
        assert "fmi2Terminate" not in proc.stderr and "internal error" not in proc.stderr
        last = proc.stdout.splitlines()[-1]
        if json_line:
            record = json.loads(last)
            assert record["status"] == "failed" and "fatal" in record["message"].lower()
        else:
            assert last.startswith("failed: ") and "fatal" in last.lower()
        assert read_run(log).metadata["result"]["status"] == "failed"


# -- item 8: journal lines are verified against the spec and the logs ------------------------------

SPEC4 = """
name = "t4"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 15.0
[grid.gains]
K_ps = [0.25, 0.5]
K_is = [0.1, 0.2]
"""


@pytest.fixture(scope="module")
def batch4(fmu3: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 4-run batch (its folder is copied, never changed)."""
    folder = tmp_path_factory.mktemp("batch4")
    (folder / "t4.toml").write_text(SPEC4)
    result = run_batch(load_batch(folder / "t4.toml"), folder / "out",
                       BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert result.counts["converged"] == 4
    return folder


def _copy(batch4: Path, tmp_path: Path, journal_of_before: Callable[[Path, Any], None]
          ) -> tuple[Path, list[dict[str, Any]]]:
    """The batch copied, its journal as batches before compact lines wrote it (the lines
    that hold their records: what an edit here changes)."""
    out = tmp_path / "out"
    shutil.copytree(batch4 / "out", out, copy_function=shutil.copy2)
    journal_of_before(out, load_batch(batch4 / "t4.toml").runs)
    lines = [json.loads(x) for x in (out / "journal.jsonl").read_text().splitlines()]
    return out, lines


def _rewrite(out: Path, lines: list[dict[str, Any]], extra: str = "") -> None:
    (out / "journal.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines) + extra)


@pytest.mark.parametrize("edit,field", [
    (lambda x: x["row"]["inputs"].update({"gains.K_ps": 999}), "row.inputs.gains.K_ps"),
    (lambda x: x["record"].update(status="failed"), "record.status"),
    (lambda x: x["row"]["inputs"].update({"gains.K_is": "abc"}), "row.inputs.gains.K_is"),
    (lambda x: x["record"].update(final_position_error_m=0.0), "record.final_position_error_m"),
    (lambda x: x["record"].update(steps="695"), "record.steps"),
    (lambda x: x["row"].update(name="other"), "row.name"),
], ids=["input", "status", "text-input", "result", "type", "name"])
def test_an_edited_journal_line_is_made_again_from_the_spec_and_the_log(
        edit: Any, field: str, batch4: Path, fmu3: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str], journal_of_before: Callable[[Path, Any], None]
        ) -> None:
    """``row.inputs."gains.K_ps"`` edited to 999 used to be in the summary, although the run
    used 0.25; ``record.status`` edited to failed likewise; ``"abc"`` was ArrowInvalid."""
    out, lines = _copy(batch4, tmp_path, journal_of_before)
    # a line of now leaves the run's inputs to the spec; one of before held them (``row``),
    # which an edit could change: line 1 is made such (sealed before the edit)
    from wmr.apps.batch import runner
    from wmr.apps.batch.journal import line_check

    runs = load_batch(batch4 / "t4.toml").runs
    assert "row" not in lines[1]
    lines[1]["row"] = runner._row_json(runs[int(lines[1]["run_id"][:4])])
    lines[1]["check"] = line_check(lines[1])
    edit(lines[1])
    _rewrite(out, lines)
    again = run_batch(load_batch(batch4 / "t4.toml"), out, BatchOptions(workers=1, fmu_path=fmu3),
                      progress=False)
    assert again.executed == [] and again.counts["converged"] == 4  # nothing redone
    assert (out / "summary.csv").read_bytes() == (batch4 / "out" / "summary.csv").read_bytes()
    err = capsys.readouterr().err
    assert f"1 line did not match the spec or the run's log (first: run {lines[1]['run_id']}, " \
           f"{field})" in err
    # the corrected line is sealed: the next resume trusts it, silently
    run_batch(load_batch(batch4 / "t4.toml"), out, BatchOptions(workers=1, fmu_path=fmu3),
              progress=False)
    assert "did not match" not in capsys.readouterr().err


def test_garbage_journal_lines_are_skipped(batch4: Path, fmu3: Path, tmp_path: Path,
                                          journal_of_before: Callable[[Path, Any], None]
                                          ) -> None:
    """A 5,000-digit run id was ValueError (int's digit limit); 100,000 ``[`` RecursionError;
    a line without a seal (or an older journal's) is made again silently."""
    out, lines = _copy(batch4, tmp_path, journal_of_before)
    del lines[0]["check"]
    _rewrite(out, lines, '{"run_id": "' + "1" * 5000 + '-0a433d73", "record": {}}\n'
             + "[" * 100_000 + "\n" + '{"run_id": "' + "7" * 60 + '", "record": {}}\n')
    again = run_batch(load_batch(batch4 / "t4.toml"), out, BatchOptions(workers=1, fmu_path=fmu3),
                      progress=False)
    assert again.executed == [] and again.skipped == 4
    assert (out / "summary.csv").read_bytes() == (batch4 / "out" / "summary.csv").read_bytes()


def test_an_edited_line_of_a_killed_run_is_redone(
        batch4: Path, fmu3: Path, tmp_path: Path,
        journal_of_before: Callable[[Path, Any], None]) -> None:
    """A killed run's record was made up by the executor: no log record to make it again
    from, so an edited one is not trusted but the run done again."""
    out, lines = _copy(batch4, tmp_path, journal_of_before)
    lines[2].update(killed=True, record={**lines[2]["record"], "status": "timeout"})
    _rewrite(out, lines)
    again = run_batch(load_batch(batch4 / "t4.toml"), out, BatchOptions(workers=1, fmu_path=fmu3),
                      progress=False)
    assert again.executed == [lines[2]["run_id"]]
    assert (out / "summary.csv").read_bytes() == (batch4 / "out" / "summary.csv").read_bytes()


def test_an_edited_compact_line_is_run_again_saying_so(
        batch4: Path, fmu3: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A compact journal line's status edited (failed for converged): its seal no longer
    matches the run's summary row, so the run is not trusted but run again, in one line."""
    out = tmp_path / "out"
    shutil.copytree(batch4 / "out", out, copy_function=shutil.copy2)
    lines = [json.loads(x) for x in (out / "journal.jsonl").read_text().splitlines()]
    assert "record" not in lines[1] and lines[1]["status"] == "converged"
    lines[1]["status"] = "failed"
    _rewrite(out, lines)
    again = run_batch(load_batch(batch4 / "t4.toml"), out, BatchOptions(workers=1, fmu_path=fmu3),
                      progress=False)
    assert again.executed == [lines[1]["run_id"]] and again.counts["converged"] == 4
    assert (out / "summary.csv").read_bytes() == (batch4 / "out" / "summary.csv").read_bytes()
    assert capsys.readouterr().err == (
        f"wmr: {out / 'journal.jsonl'}: 1 journalled run had no summary row matching its "
        f"line, or no finished log (first: run {lines[1]['run_id']}): run again\n")


def test_records_made_again_from_logs_are_the_journalled_ones(
        fmu3: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        journal_of_before: Callable[[Path, Any], None]) -> None:
    """Runs stopped by their wall-clock limit (logged failed, journalled timeout) and finished
    ones: every line unsealed, each is made again from its log, equal to what was written."""
    spec = tmp_path / "t4.toml"
    # two short runs and two of 10,000 steps, which 20 ms of wall clock cannot hold (the PI
    # compiled into the stepper finishes a short run in a few ms)
    spec.write_text(SPEC4.replace("max_time_s = 15.0", "max_time_s = 150.0")
                    .replace("K_is = [0.1, 0.2]", "K_is = [0.1, 0.2]\n[grid.start]\n"
                             "x_m = [1.0, 100.0]").replace("[grid.gains]\nK_ps = [0.25, 0.5]",
                                                           "[grid.gains]\nK_ps = [0.5]"))
    out = tmp_path / "out"
    first = run_batch(load_batch(spec), out,
                      BatchOptions(workers=1, run_timeout_s=0.02, fmu_path=fmu3), progress=False)
    assert first.counts["timeout"] >= 1
    journal_of_before(out, load_batch(spec).runs)  # lines that hold their records
    lines = [json.loads(x) for x in (out / "journal.jsonl").read_text().splitlines()]
    summary = (out / "summary.csv").read_bytes()
    _rewrite(out, [{k: v for k, v in x.items() if k != "check"} for x in lines])
    again = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.executed == [] and (out / "summary.csv").read_bytes() == summary
    remade = [json.loads(x) for x in (out / "journal.jsonl").read_text().splitlines()][4:]
    assert [x["record"] for x in remade] == [x["record"] for x in lines]
    assert "did not match" not in capsys.readouterr().err


def test_a_batch_folder_removed_under_the_workers_is_one_error_not_a_traceback(
        fmu3: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """A worker (re)started after the folder went could not open its log file: it printed a
    traceback; now the batch stops with one line saying so."""
    from wmr.apps.batch.local import LocalPool
    from wmr.apps.batch.spec import BatchRun
    from wmr.apps.batch.worker import Block

    spec = load_scenario("fig11").runs[0]

    class _one_block:  # the pool's source of runs: one block of one run
        def __init__(self, spec: Any) -> None:
            self.block = Block(range(1), {0: BatchRun("0000-x", spec, spec.name, "", {}, "x")},
                               1, (), "f")

        def __len__(self) -> int:
            return 1

        def blocks(self, size: int) -> Any:
            yield self.block

    pool = LocalPool(fmu3, tmp_path / "runs", 1, log_dir=tmp_path / "gone")
    with pytest.raises(WmrError, match=r"could not start: .*worker-0\.log: cannot create"):
        list(pool.run(_one_block(spec)))
    assert "Traceback" not in capfd.readouterr().err


# -- item 4 (part C): a worker stopped by SIGSTOP ----------------------------------------------

def test_a_stopped_worker_s_run_has_a_null_log_not_a_missing_one(
        fmu3: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A worker SIGSTOPped between runs never reads its next run: the pool kills it at the hard
    limit and the run is ``timeout`` with no log at all.  Its summary row named
    ``runs/<id>.mcap``, a file that does not exist; now it says null, ``wmr report`` reads the
    summary, and a resume trusts the killed run's line (nothing redone)."""
    spec = tmp_path / "t4.toml"
    spec.write_text(SPEC4)
    out = tmp_path / "out"
    stopped: list[int] = []

    def stop_the_worker(outcome: Any) -> None:
        if not stopped:  # the worker waits for its next run: it will never read it
            stopped.append(int(outcome.worker))
            os.kill(stopped[0], signal.SIGSTOP)

    first = run_batch(load_batch(spec), out,
                      BatchOptions(workers=1, run_timeout_s=1.0, fmu_path=fmu3), progress=False,
                      on_outcome=stop_the_worker)
    assert first.counts["timeout"] >= 1 and len(first.executed) == 4
    killed = first.executed[1]
    rows = {r["run_id"]: r for r in pq.read_table(out / "summary.parquet").to_pylist()}
    assert rows[killed]["status"] == "timeout" and rows[killed]["mcap"] is None
    for row in rows.values():  # every log a row names exists
        assert row["mcap"] is None or (out / row["mcap"]).is_file()
    assert sum(row["mcap"] is None for row in rows.values()) == 1
    csv_rows = (out / "summary.csv").read_text().splitlines()
    assert next(r for r in csv_rows if r.startswith(killed)).endswith(",")  # empty cell
    assert main(["report", str(out)]) == 0
    summary = (out / "summary.csv").read_bytes()
    again = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.executed == [] and (out / "summary.csv").read_bytes() == summary
    assert "did not match" not in capsys.readouterr().err


# -- item 3 (part C): ulimit -v too low to load the modules ------------------------------------

def _limited(resource_name: str, value: int) -> Any:
    """A ``preexec_fn`` that sets both limits of ``resource_name`` to ``value``."""
    import resource

    def set_limit() -> None:
        which = getattr(resource, resource_name)
        resource.setrlimit(which, (value, value))

    return set_limit


@pytest.mark.parametrize("argv", [["--version"], ["batch", "SPEC", "--workers", "2"]],
                         ids=["version", "batch"])
def test_ulimit_v_below_what_the_modules_need_is_one_line(argv: list[str],
                                                          tmp_path: Path) -> None:
    """``ulimit -v 150000``: numpy's import failed inside ``build_parser`` (a SyntaxError
    from the parser's failed allocation, or numpy's 30-line ImportError, or OpenBLAS ending
    the process); now one line before any heavy import."""
    spec = tmp_path / "t4.toml"
    spec.write_text(SPEC4)
    argv = [str(spec) if a == "SPEC" else a for a in argv]
    proc = subprocess.run([sys.executable, "-m", "wmr.cli", *argv, "--out", str(tmp_path / "o")]
                          if argv[0] == "batch" else [sys.executable, "-m", "wmr.cli", *argv],
                          capture_output=True, text=True, timeout=120,
                          preexec_fn=_limited("RLIMIT_AS", 150_000 * 1024))
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.startswith("wmr: error: out of memory: ulimit -v is 150000 kB")
    assert "raise it (e.g. ulimit -v" in proc.stderr and proc.stderr.count("\n") == 1


@pytest.mark.parametrize("where", ["parser", "handler"])
def test_a_module_that_cannot_be_mapped_is_out_of_memory_not_an_internal_error(
        where: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Above the floor a sub-command's module may still not fit: pyarrow's ImportError
    ``libarrow.so.2600: failed to map segment from shared object`` was an internal error."""
    import wmr.cli as cli

    def unmappable(*args: Any) -> Any:
        raise ImportError("libarrow.so.2600: failed to map segment from shared object")

    if where == "parser":
        monkeypatch.setattr(cli, "_extra_commands", unmappable)
    else:
        monkeypatch.setattr(cli, "_cmd_fmu_build", unmappable)  # looked up by build_parser
    assert main(["fmu", "build"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("wmr: error: out of memory loading wmr's modules") and \
        err.count("\n") == 1


def test_a_missing_module_is_not_called_out_of_memory(monkeypatch: pytest.MonkeyPatch) -> None:
    import wmr.cli as cli

    def missing() -> Any:
        raise ModuleNotFoundError("No module named 'rerun'")

    monkeypatch.setattr(cli, "_extra_commands", missing)
    with pytest.raises(ModuleNotFoundError):
        main(["--version"])


# -- items 1 and 2 (part C): an open-file limit too low for the pool ---------------------------

@pytest.mark.parametrize("limit", [12, 16])
def test_ulimit_n_too_low_for_the_workers_is_one_line_at_once(limit: int, fmu3: Path,
                                                               tmp_path: Path) -> None:
    """``ulimit -n 12`` with two workers could hang; ``ulimit -n 16`` printed the forkserver's
    ``EOFError`` traceback before its line.  Now one line naming the limit and the fix, before
    any worker (or the forkserver) is started.  60 s is the hang's failure condition only."""
    spec = tmp_path / "t4.toml"
    spec.write_text(SPEC4)
    proc = subprocess.run([sys.executable, "-m", "wmr.cli", "batch", str(spec), "--workers",
                           "2", "--fmu", str(fmu3), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=60,
                          preexec_fn=_limited("RLIMIT_NOFILE", limit))
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.startswith(f"wmr: error: the open-file limit (ulimit -n) is {limit}, "
                                  "and 2 workers need about ")
    assert "raise it (e.g. ulimit -n 256)" in proc.stderr and proc.stderr.count("\n") == 1
    assert not (tmp_path / "out" / "logs").exists()  # no worker was started


def test_a_low_soft_open_file_limit_is_raised_to_what_the_workers_need(fmu3: Path,
                                                                        tmp_path: Path) -> None:
    """``ulimit -S -n 12`` under a higher hard limit: the batch raises its own soft limit."""
    import resource

    spec = tmp_path / "t4.toml"
    spec.write_text(SPEC4)
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]

    def soft_12() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (12, hard))

    proc = subprocess.run([sys.executable, "-m", "wmr.cli", "batch", str(spec), "--workers",
                           "2", "--fmu", str(fmu3), "--out", str(tmp_path / "out"),
                           "--no-progress"],
                          capture_output=True, text=True, timeout=120, preexec_fn=soft_12)
    assert proc.returncode == 0, proc.stderr
    assert "4 converged" in proc.stderr


def test_a_worker_gone_while_a_helper_keeps_its_pipe_open_is_seen_dead(fmu3: Path,
                                                                       tmp_path: Path) -> None:
    """A worker whose FMU started a helper process (which inherits the worker's pipe) and
    crashed: the pipe never read as EOF, and a batch without a run timeout waited for ever.
    The pool now watches the process itself: the run is retried once, then ``failed``.  Run in
    a subprocess so that the old hang is a failure after 60 s, not a stuck test session."""
    spec = tmp_path / "t4.toml"
    spec.write_text(SPEC4)
    out = tmp_path / "out"
    script = (
        "import sys\n"
        "from wmr.apps.batch import BatchOptions, load_batch, run_batch\n"
        "from wmr.apps.batch.runner import _test_hooks\n"
        f"batch = load_batch({str(spec)!r})\n"
        "with _test_hooks(faults={batch.runs[0].run_id: 'crash-keeping-pipe'}):\n"
        f"    r = run_batch(batch, {str(out)!r},\n"
        f"                  BatchOptions(workers=1, fmu_path={str(fmu3)!r}), progress=False)\n"
        "print(r.counts['failed'], r.counts['converged'])\n")
    err = tmp_path / "stderr.txt"
    try:  # files, not pipes: the helper keeps the forkserver, and its stderr, alive
        with open(err, "w") as stderr, open(tmp_path / "stdout.txt", "w") as stdout:
            proc = subprocess.run([sys.executable, "-c", script], stdout=stdout, stderr=stderr,
                                  timeout=60)
    finally:
        for marker in (out / "runs").rglob("*.helpers"):
            for pid in marker.read_text().split():
                try:
                    os.kill(int(pid), signal.SIGKILL)
                except ProcessLookupError:
                    pass
    assert proc.returncode == 0, err.read_text()
    assert (tmp_path / "stdout.txt").read_text().split() == ["1", "3"]
    rows = {r["run_id"]: r for r in pq.read_table(out / "summary.parquet").to_pylist()}
    assert "died" in min(rows.values(), key=lambda r: r["run_id"])["message"]


# -- issue 28 items 5 and 10: inputs that are not regular files, or too large -----------------

def _special(kind: str, tmp_path: Path) -> str:
    """A character device (``/dev/zero``) or a FIFO nobody writes to."""
    if kind == "zero":
        return "/dev/zero"
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    return str(fifo)


_KIND_WORDS = {"zero": "/dev/zero is a character device, not a regular file",
               "fifo": "fifo is a named pipe (FIFO), not a regular file"}


@pytest.mark.parametrize("kind", ["zero", "fifo"])
@pytest.mark.parametrize("case", ["scenario", "map", "spec", "spec-fmu_map", "spec-fmu"])
def test_a_device_or_fifo_as_an_input_is_refused_at_once(case: str, kind: str,
                                                         tmp_path: Path) -> None:
    """``/dev/zero`` as scenario, map or spec grew to 22.7 GB until the kernel killed it; a
    FIFO blocked for ever; as a spec's ``fmu`` both were hashed for ever.  Run in a
    subprocess under ``ulimit -v`` and a timeout, so that the old behaviour fails the test
    instead of taking the machine."""
    special = _special(kind, tmp_path)
    spec = tmp_path / "t4.toml"
    field = {"scenario": "scenario", "map": "--map", "spec": "spec", "spec-fmu_map": "--map",
             "spec-fmu": special}[case]
    if case == "spec-fmu_map":
        spec.write_text(f'fmu_map = "{special}"\n{SPEC4}')
    elif case == "spec-fmu":
        spec.write_text(f'fmu = "{special}"\n{SPEC4}')
    argv = {"scenario": ["run", special], "map": ["run", "fig11", "--map", special],
            "spec": ["batch", special]}.get(case, ["batch", str(spec)])
    proc = subprocess.run([sys.executable, "-m", "wmr.cli", *argv, "--out",
                           str(tmp_path / ("o.mcap" if argv[0] == "run" else "o"))],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path,
                          preexec_fn=_limited("RLIMIT_AS", 3 << 30))
    assert proc.returncode == 1, proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    words = _KIND_WORDS[kind].replace(" is a", ": is a") if field == special else _KIND_WORDS[kind]
    assert line.startswith(f"wmr: error: {field}: ") and words in line, line
    assert not (tmp_path / "o.mcap").exists()


def test_a_toml_input_is_read_no_further_than_its_limit(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A scenario, spec or map larger than the limit is refused naming the limit's value."""
    import wmr.config.scenario as scenario_module

    monkeypatch.setattr(scenario_module, "MAX_TOML_BYTES", 1000)
    path, small = tmp_path / "big.toml", tmp_path / "small.toml"
    path.write_text(FIG11 + "#" * 1000 + "\n")
    small.write_text(FIG11)
    for argv in (["run", str(path)], ["batch", str(path)], ["run", str(small), "--map", str(path)]):
        assert main([*argv, "--out", str(tmp_path / "o.mcap")]) == 1
        line = capsys.readouterr().err.splitlines()[-1]  # after the FMU build's, if any
        assert line.startswith("wmr: error: ") and (
            f"{path} is larger than 1000 bytes, the most wmr reads of a TOML file (give ") in line


def test_read_input_stops_at_its_limit_when_the_size_lies(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """A file that grows while it is read, or whose size says 0 (``/proc``), is read no
    further than the limit, and refused."""
    from wmr.infra import inputs

    path = tmp_path / "f"
    path.write_bytes(b"x" * 5000)
    real_fstat = os.fstat

    def small(fd: int) -> os.stat_result:
        st = real_fstat(fd)
        return os.stat_result((st.st_mode, *st[1:6], 0, *st[7:]))

    monkeypatch.setattr(inputs.os, "fstat", small)
    assert inputs.read_input(path, "f", max_bytes=5000) == b"x" * 5000
    with pytest.raises(ConfigError, match=r"^f: .* is larger than 4999 bytes, the most wmr "
                                          r"reads of a file \(give a regular file\)$"):
        inputs.read_input(path, "f", max_bytes=4999)
    with pytest.raises(ConfigError, match="is larger than 4999 bytes"):
        inputs.sha256_input(path, "f", max_bytes=4999)


def test_an_fmu_is_hashed_only_up_to_its_limit(fmu3: Path, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    import hashlib

    import wmr.adapters.fmi.archive as archive

    assert archive.file_sha256(fmu3) == hashlib.sha256(fmu3.read_bytes()).hexdigest()
    monkeypatch.setattr(archive, "MAX_ARCHIVE_BYTES", 1000)
    spec = tmp_path / "t4.toml"
    spec.write_text(SPEC4)
    assert main(["batch", str(spec), "--fmu", str(fmu3), "--out", str(tmp_path / "o"),
                 "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and (f"{fmu3}: is larger than 1000 bytes, the most wmr reads "
                                     "of an FMU (give an FMU file)") in err, err


@pytest.mark.parametrize(("content", "message"), [
    (b'[variables]\n# caf\xe9\n', "is not UTF-8 text (byte 0xe9 at offset 17)"),
    (b"unmapped = " + b"[" * 50_000 + b"]" * 50_000 + b"\n", "nests arrays or tables too deeply"),
])
@pytest.mark.parametrize("command", ["run", "batch", "ssp export"])
def test_a_bad_map_file_is_the_scenarios_one_line(
        command: str, content: bytes, message: str, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 28 item 10: ``UnicodeDecodeError`` and ``RecursionError`` from ``--map``."""
    path = tmp_path / "bad_map.toml"
    path.write_bytes(content)
    out = tmp_path / {"run": "o.mcap", "batch": "o", "ssp export": "o.ssp"}[command]
    target = "fig9" if command == "batch" else "fig11"
    assert main([*command.split(), target, "--map", str(path), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"wmr: error: --map: {path} {message} (") and err.count("\n") == 1, err


def test_tuned_gains_are_read_as_every_input(tmp_path: Path) -> None:
    """``--tuned``: a FIFO blocked ``read_text`` for ever (subprocess, timeout); a file
    written by ``wmr tune --save`` still reads."""
    from wmr.apps.benchmark import load_tuned

    good = tmp_path / "tuned.json"
    good.write_text(json.dumps({"pi": {"K_ps": 0.75}}))
    assert load_tuned(good)["pi"]["K_ps"] == 0.75
    fifo = _special("fifo", tmp_path)
    script = f"from wmr.apps.benchmark import load_tuned\nload_tuned({fifo!r})\n"
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 1 and proc.stderr.strip().splitlines()[-1].endswith(
        f"ConfigError: tuned: {_KIND_WORDS['fifo'].replace('fifo', fifo)} (give a file "
        "written by 'wmr tune --save')"), proc.stderr

"""The Python API (issue 11, item 2): the example of docs/api.md runs as written, ``import
wmr`` loads nothing heavy, and the API names stay callable when their modules are imported."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

import wmr
from wmr.infra.paths import _REPO_ROOT

DOC = _REPO_ROOT / "docs" / "api.md"


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_the_documented_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    blocks = _python_blocks(DOC.read_text(encoding="utf-8"))
    assert len(blocks) >= 4
    namespace: dict[str, object] = {}
    for block in blocks:
        exec(compile(block, str(DOC), "exec"), namespace)
    res = namespace["res"]
    assert isinstance(res, wmr.RunResult)
    assert "<table>" in res._repr_html_() and "converged" in res._repr_html_()
    assert "masses" in namespace["sweep"]._repr_html_()  # type: ignore[attr-defined]


def test_import_wmr_loads_nothing_heavy() -> None:
    code = ("import sys, wmr; heavy = [m for m in ('numpy', 'pandas', 'wmr.api', 'casadi', "
            "'fmpy') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env={"PYTHONPATH": str(_REPO_ROOT / "pipelines")})
    assert out.stdout.strip() == "[]"


def test_api_names_are_the_api_functions_after_every_module_is_imported() -> None:
    import types

    import wmr.adapters.ocp
    import wmr.api
    import wmr.apps.batch
    import wmr.apps.run

    for name in ("run", "batch", "optimal"):
        # plain functions, whatever the library imported before: no module under their names
        assert getattr(wmr, name) is getattr(wmr.api, name)
        assert isinstance(getattr(wmr, name), types.FunctionType)
    for name in ("load_scenario", "read_log", "Log", "RunResult", "BatchResult"):
        assert name in dir(wmr) and getattr(wmr, name) is not None
    with pytest.raises(AttributeError):
        _ = wmr.no_such_thing  # type: ignore[attr-defined]


def test_api_input_errors_name_the_argument(tmp_path: Path) -> None:
    from wmr.infra.errors import ConfigError

    with pytest.raises(ConfigError, match=r"params\.m"):
        wmr.run(params={"m": 0.0}, out=tmp_path / "x.mcap")
    with pytest.raises(ConfigError, match="goal"):
        wmr.run(goal=(1.0, 2.0), out=tmp_path / "x.mcap")
    assert not (tmp_path / "x.mcap").exists()


def test_a_run_reads_its_log_only_when_its_signals_are_asked(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``wmr.run`` costs what ``wmr run`` costs (issue 31): the log is not read into memory
    when the run ends, only when ``.path``/``.signals``/``.log`` first need it, and then once;
    ``.path`` alone reads the path's topic alone.  Seen failing when ``run`` read the log
    eagerly (``read_log`` called before any access), and with ``.path`` reading it whole."""
    import wmr.api

    reads: list[tuple[Path, object]] = []
    real_read_log = wmr.api.read_log

    def counting_read_log(path: str | Path, **kwargs: object) -> wmr.Log:
        reads.append((Path(path), kwargs.get("signals")))
        return real_read_log(path, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(wmr.api, "read_log", counting_read_log)
    res = wmr.run("fig11", max_time_s=2.0, out=tmp_path / "short.mcap")
    assert res.status == "timeout" and res.mcap == tmp_path / "short.mcap"
    assert reads == []  # the record alone: nothing read yet
    path = res.path
    # the path alone (its topic, /robot/state), kept: asked again, not read again
    assert reads == [(tmp_path / "short.mcap", wmr.api.PATH_COLUMNS)] and res.path is path
    # the path read back is the run's: 2 s of 10 ms steps, starting at fig11's start
    assert len(path) == 201 and path["x_m"].iloc[0] == 0.0
    assert res.signals.shape[0] == 201 and res.log is not None
    assert res.log.path.equals(path) and list(path) == list(wmr.api.PATH_COLUMNS)
    assert reads[1:] == [(tmp_path / "short.mcap", None)]  # the whole log once, then kept
    assert res.path.equals(path) and len(reads) == 2
    no_log = wmr.RunResult({"name": "x", "status": "converged", "mcap": None})
    assert no_log.log is None and len(reads) == 2

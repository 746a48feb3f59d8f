"""``wmr.replay(..., notebook=True)``: the replay shown inline in a notebook, through
rerun-notebook (the ``notebook`` extra), checked by executing a notebook headless."""

from __future__ import annotations

from pathlib import Path

import pytest

import wmr
from wmr.adapters.rerun.replay import NOTEBOOK_EXTRA
from wmr.infra.errors import ConfigError

#: The mime type of an ipywidget in a cell's output (the viewer is one).
WIDGET_MIME = "application/vnd.jupyter.widget-view+json"


def test_a_notebook_executed_headless_shows_the_replay_inline(
        fig11_log: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("rerun_notebook", reason="rerun-notebook is not installed: "
                        f"{NOTEBOOK_EXTRA}")
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    kernelspec = pytest.importorskip("ipykernel.kernelspec")

    # the kernel runs this interpreter (its venv, and this tree's wmr through PYTHONPATH)
    kernelspec.install(prefix=str(tmp_path))
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "share" / "jupyter"))
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(
        "import wmr\n"
        f"result = wmr.replay({str(fig11_log)!r}, notebook=True)\n"
        # what the widget got, queued until a front end loads it (none runs headless)
        "queued = [b for event, bs in result.viewer._viewer._event_queue\n"
        "          if event == {'type': 'rrd'} for b in bs or ()]\n"
        "print(result.runs, result.rrd, result.spawned, len(queued),\n"
        "      sum(len(b) for b in queued))")]
    nbclient.NotebookClient(nb, timeout=120, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()

    outputs = nb.cells[0].outputs
    views = [o for o in outputs if WIDGET_MIME in o.get("data", {})]
    assert any("rerun_notebook.Viewer" in v["data"]["text/plain"] for v in views), outputs
    printed = "".join(o["text"] for o in outputs if o.get("name") == "stdout").split()
    assert printed[:3] == ["['fig11']", "None", "False"], printed
    messages, size_b = int(printed[3]), int(printed[4])
    # the whole recording went to the widget: the run's grid, summary and thousands of steps
    assert messages > 10 and size_b > 100_000, printed
    assert not list(tmp_path.rglob("*.rrd")) and not fig11_log.with_suffix(".rrd").exists()


def test_without_rerun_notebook_one_error_names_the_extra(
        fig11_log: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import rerun.notebook

    monkeypatch.setattr(rerun.notebook, "HAS_NOTEBOOK", False)  # as without rerun-notebook
    with pytest.raises(ConfigError) as err:
        wmr.replay(fig11_log, notebook=True)
    assert str(err.value) == ("notebook: the inline viewer needs rerun-notebook, which is not "
                              "installed (pip install 'wmr-cosim[notebook]')")
    assert not fig11_log.with_suffix(".rrd").exists()


def test_outside_a_notebook_or_with_an_rrd_it_is_refused(fig11_log: Path,
                                                         tmp_path: Path) -> None:
    pytest.importorskip("rerun_notebook", reason=f"rerun-notebook is not installed: "
                        f"{NOTEBOOK_EXTRA}")
    with pytest.raises(ConfigError, match=r"^notebook: not in a notebook: .*\(call it from "):
        wmr.replay(fig11_log, notebook=True)
    with pytest.raises(ConfigError, match=r"^notebook: given with rrd \(give one of them"):
        wmr.replay(fig11_log, notebook=True, rrd=tmp_path / "x.rrd")
    assert not list(tmp_path.iterdir())

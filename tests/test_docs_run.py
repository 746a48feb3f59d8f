"""Every code block of ``docs/`` and the README runs as written (issue 21, item 2).

* ```` ```python ```` blocks of each page run in order in one namespace, in an empty folder,
  as in a notebook (``__name__ == "__main__"``); the blocks that cannot run here are in
  :data:`SKIP`, each with the reason.  The script of ``docs/api.md`` also runs as a file, with
  and without its ``__main__`` guard (batch workers do not import the script).
* ```` ```toml ```` blocks parse.
* The ``wmr ...`` synopsis lines of the plain blocks name real commands and options.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from wmr.infra.paths import _REPO_ROOT

PAGES = [*sorted((_REPO_ROOT / "docs").glob("*.md")), _REPO_ROOT / "README.md"]
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", flags=re.S | re.M)

#: (page, first line of the block) -> why it cannot run in the tests.
SKIP: dict[tuple[str, str], str] = {
    # a fragment: `...` stands for the run's arguments, and the live view needs a Rerun viewer
    ("replay.md", "with RunLogWriter(path, run=..., goal=...) as log, "
                  "live_view_sink(spec.name, spec.goal, None) as live:"):
        "a fragment of the loop's code with elided arguments",
    # other tools reading `wmr ssp export`'s package: tests/test_ssp.py runs both
    ("ssp.md", "from libcosimpy.CosimExecution import CosimExecution"):
        "needs ssp/fig11.ssp from `wmr ssp export`; tests/test_ssp.py runs it",
    ("ssp.md", "from fmpy.ssp.simulation import simulate_ssp"):
        "needs ssp/fig11.ssp from `wmr ssp export`; tests/test_ssp.py runs it",
    ("ssp.md", "from wmr.adapters.ssp.ecos import simulate_ecos"):
        "needs ssp/fig11-fmi3.ssp from `wmr ssp export --fmi 3`; tests/test_ssp.py runs it",
    # a 1000-run batch's summary: tests/test_batch_controllers.py pairs a small one the same way
    ("batch.md", "import pandas as pd"):
        "needs batches/pi_vs_astolfi from `wmr batch pi_vs_astolfi`; "
        "tests/test_batch_controllers.py runs the same pivot on a real batch",
}
#: Pages whose python blocks take minutes (FMU runs, a batch, an optimal solve).
SLOW_PAGES = {"api.md"}


def _blocks(page: Path, lang: str) -> list[str]:
    return [body for tag, body in FENCE.findall(page.read_text(encoding="utf-8"))
            if tag == lang]


def _skipped(page: Path, block: str) -> bool:
    return (page.name, block.strip().splitlines()[0]) in SKIP


def test_the_skip_list_names_blocks_that_exist() -> None:
    """A stale entry would hide nothing and mislead: every skipped block is still there."""
    present = {(p.name, b.strip().splitlines()[0]) for p in PAGES for b in _blocks(p, "python")}
    assert set(SKIP) <= present, set(SKIP) - present


PYTHON_PAGES = [p for p in PAGES
                if any(not _skipped(p, b) for b in _blocks(p, "python"))]


@pytest.mark.parametrize("page", [
    pytest.param(p, marks=[pytest.mark.slow] if p.name in SLOW_PAGES else [], id=p.name)
    for p in PYTHON_PAGES])
def test_python_blocks_run_as_in_a_notebook(page: Path, tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "__main__"}
    for block in _blocks(page, "python"):
        if not _skipped(page, block):
            exec(compile(block, str(page), "exec"), namespace)


def _api_script() -> str:
    scripts = [b for b in _blocks(_REPO_ROOT / "docs" / "api.md", "python")
               if 'if __name__ == "__main__":' in b]
    assert len(scripts) == 1, "docs/api.md shows one script with the __main__ guard"
    return scripts[0]


def _run_script(text: str, folder: Path) -> subprocess.CompletedProcess[str]:
    (folder / "sweep.py").write_text(text, encoding="utf-8")
    env = {"PYTHONPATH": str(_REPO_ROOT / "pipelines"), "PATH": "/usr/bin:/bin",
           **{k: v for k, v in __import__("os").environ.items()
              if k in ("HOME", "WMR_CACHE_DIR", "XDG_CACHE_HOME", "MPLBACKEND")}}
    return subprocess.run([sys.executable, "sweep.py"], cwd=folder, capture_output=True,
                          text=True, env=env, timeout=600)


@pytest.mark.slow
def test_the_api_script_runs_as_a_file(tmp_path: Path) -> None:
    proc = _run_script(_api_script(), tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "converged" in proc.stdout


@pytest.mark.slow
def test_the_script_without_its_guard_runs_its_batch(tmp_path: Path) -> None:
    """A script that calls ``wmr.batch`` at its top level runs as a saved file (issue 30):
    the batch's workers do not import the script again.  Before, each worker ran the
    script's top level again and the API stopped it with "put its code under `if __name__ ==
    "__main__":`" (issue 21's guard, which had replaced a batch inside the batch)."""
    guarded = _api_script()
    unguarded = guarded.replace('if __name__ == "__main__":\n    main()', "main()")
    assert unguarded != guarded
    proc = _run_script(unguarded, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "__main__" not in proc.stderr, proc.stderr
    # the summary, printed once (a worker that ran the script would print it again)
    assert proc.stdout.count("params.m") == 1, proc.stdout
    assert "20.0" in proc.stdout and "40.0" in proc.stdout
    assert proc.stdout.count("converged") == 2, proc.stdout
    assert len(list((tmp_path / "batches").glob("*/summary.parquet"))) == 1


@pytest.mark.parametrize("page", [p for p in PAGES if _blocks(p, "toml")], ids=lambda p: p.name)
def test_toml_blocks_parse(page: Path) -> None:
    for block in _blocks(page, "toml"):
        tomllib.loads(block)


def _synopses() -> list[tuple[str, list[str]]]:
    """``(page, words)`` of each line of a plain block that starts with ``wmr``, with the
    continuation lines of a synopsis joined."""
    found = []
    for page in PAGES:
        for block in _blocks(page, ""):
            lines = block.splitlines()
            for i, line in enumerate(lines):
                if not line.startswith("wmr "):
                    continue
                text = line
                for more in lines[i + 1:]:
                    if not more.startswith(" "):
                        break
                    text += " " + more.strip()
                found.append((page.name, shlex.split(text.split("#")[0], posix=True)))
    return found


@pytest.mark.parametrize("page, words", _synopses(),
                         ids=[f"{p}:{' '.join(w[:3])}" for p, w in _synopses()])
def test_wmr_synopses_name_real_commands_and_options(page: str, words: list[str]) -> None:
    import argparse

    from wmr.cli import build_parser

    parser: argparse.ArgumentParser = build_parser()
    for word in words[1:]:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or word not in subs[0].choices:
            break
        parser = subs[0].choices[word]
    options = {o for a in parser._actions for o in a.option_strings}
    # an option starts a word (not the '-then' of a name such as turn-then-drive)
    used = {w.split("=")[0] for w in re.findall(r"(?<![\w-])--?[a-zA-Z][\w-]*", " ".join(words))}
    assert used <= options, f"{page}: {' '.join(words)}: unknown {sorted(used - options)}"

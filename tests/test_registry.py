"""The controller registry (``wmr.core.control.registry``) and its plug-ins (``wmr.infra.plugins``).

The worked example of ``docs/plugins.md``, ``examples/wmr_example_controller``, is installed
into a temporary folder as pip installs it (the package and a ``.dist-info`` with the entry
points its ``pyproject.toml`` declares; offline, without a build backend) next to a broken
plug-in, and run through ``wmr run``, ``wmr batch``, ``wmr benchmark`` and ``wmr tune`` in
subprocesses that find it on ``PYTHONPATH``: real entry-point discovery, no edit to ``wmr``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

import wmr
from wmr.core.control import registry
from wmr.core.plant import Pose
from wmr.core.runspec import RunSpec
from wmr.core.signals import LAW_SIGNALS
from wmr.infra import plugins
from wmr.infra.errors import ConfigError

_REPO = Path(__file__).resolve().parents[1]
EXAMPLE = _REPO / "examples" / "wmr_example_controller"
NAME = "turn-then-drive"
#: The signals the example's law fills (its SIGNALS, read here from the docs' own listing).
EXAMPLE_SIGNALS = ("dr_m", "e_s_m", "e_theta_rad", "alpha_rad", "u_s_mps", "u_theta_radps",
                   "omega_r_ref_radps", "omega_l_ref_radps")


def _dist_info(site: Path, project: str, version: str,
               entry_points: dict[str, dict[str, str]]) -> None:
    """What pip writes for an installed distribution: METADATA and entry_points.txt."""
    info = site / f"{project.replace('-', '_')}-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project}\n"
                                   f"Version: {version}\n", encoding="utf-8")
    lines = []
    for group, eps in entry_points.items():
        lines.append(f"[{group}]")
        lines += [f"{name} = {value}" for name, value in eps.items()]
    (info / "entry_points.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")


def install_example(site: Path) -> None:
    """Install ``examples/wmr_example_controller`` into ``site`` from its pyproject.toml."""
    project = tomllib.loads((EXAMPLE / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    for package in ("wmr_example_controller",):
        shutil.copytree(EXAMPLE / package, site / package)
    _dist_info(site, project["name"], project["version"], project["entry-points"])


def install_broken(site: Path) -> None:
    """A plug-in whose module does not exist (a package installed without its code)."""
    _dist_info(site, "wmr-broken-controller", "1.0",
               {registry.ENTRY_POINT_GROUP: {"broken": "wmr_no_such_module:CONTROLLER"}})


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("site")
    install_example(root)
    install_broken(root)
    return root


def _wmr(site: Path, *args: str, timeout: float = 600.0) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(_REPO / "pipelines")])
    return subprocess.run([sys.executable, "-m", "wmr.cli", *args], capture_output=True,
                          text=True, env=env, timeout=timeout, check=False)


@pytest.fixture
def on_path(site: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The site on this process's path, the registry's memory of plug-ins forgotten."""
    monkeypatch.syspath_prepend(str(site))
    plugins.entry_points.cache_clear()
    registry._plugin.cache_clear()
    yield site
    sys.modules.pop("wmr_example_controller", None)
    plugins.entry_points.cache_clear()
    registry._plugin.cache_clear()


def test_the_example_runs_in_wmr_run_and_logs_its_signals(site: Path, tmp_path: Path) -> None:
    log = tmp_path / "t.mcap"
    proc = _wmr(site, "run", "--controller", NAME, "--goal", "4", "2", "90", "--out", str(log),
                "--json")
    assert proc.returncode == 0, proc.stderr
    record = json.loads(proc.stdout.splitlines()[-1])
    assert record["status"] == "converged"
    assert record["final_position_error_m"] <= 0.05  # within the stop radius
    # turn in place, then drive straight: the path is the straight line to the goal
    straight = math.hypot(4.0, 2.0)
    assert abs(record["path_length_m"] - straight) <= 0.05 + 0.01 * straight
    read = wmr.read_log(log)
    assert read.metadata["run"]["controller"] == NAME
    sig = read.signals
    for name in EXAMPLE_SIGNALS:  # what it fills, in every row
        assert np.isfinite(sig[name].to_numpy()).all(), name
    for name in set(LAW_SIGNALS) - set(EXAMPLE_SIGNALS):  # the rest: NaN
        assert np.isnan(sig[name].to_numpy()).all(), name
    # its own signals in their own columns: the distance is the distance to the goal
    np.testing.assert_allclose(sig["dr_m"], np.hypot(4.0 - sig["x_m"], 2.0 - sig["y_m"]),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(sig["u_s_mps"], 0.5 * 0.15 * (sig["omega_r_ref_radps"]
                                                            + sig["omega_l_ref_radps"]),
                               rtol=1e-9, atol=1e-12)


def test_the_example_is_a_dimension_of_wmr_batch(site: Path, tmp_path: Path) -> None:
    spec = tmp_path / "plug.toml"
    spec.write_text('name = "plug"\nstart = [0.0, 0.0, 0.0]\ngoal = [3.0, -1.0, 0.0]\n'
                    'max_time_s = 40.0\n[grid]\ncontroller = ["pi", "turn-then-drive"]\n'
                    "[grid.start]\nheading_deg = [0.0, 120.0]\n", encoding="utf-8")
    proc = _wmr(site, "batch", str(spec), "--out", str(tmp_path / "b"), "--workers", "1",
                "--no-progress")
    assert proc.returncode == 0, proc.stderr
    import pandas as pd

    rows = pd.read_parquet(tmp_path / "b" / "summary.parquet")
    assert sorted(rows["controller"]) == ["pi", "pi", NAME, NAME]
    assert (rows["status"] == "converged").all()
    mine = rows[rows["controller"] == NAME]
    # from either heading it turns in place, then drives the straight line (to within the stop
    # radius, where it stops)
    straight = math.hypot(3.0, 1.0)
    assert (abs(mine["path_length_m"] - straight) <= 0.05 + 0.01 * straight).all()
    # the PI's way is the other, a curve (ROC): the two controllers really ran
    assert (rows[rows["controller"] == "pi"]["path_length_m"] > straight + 0.05).all()


def test_the_example_runs_in_wmr_benchmark_and_wmr_tune(site: Path, tmp_path: Path) -> None:
    out = tmp_path / "bench"
    proc = _wmr(site, "benchmark", "fig11", "--controllers", f"pi,{NAME}", "--no-optimal",
                "--out", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    rows = {r["controller"]: r for r in json.loads(proc.stdout.splitlines()[-1])}
    assert set(rows) == {"pi", NAME}
    assert rows[NAME]["status"] == "converged"
    assert Path(rows[NAME]["mcap"]) == out / "logs" / NAME / "fig11.mcap"
    assert wmr.read_log(rows[NAME]["mcap"]).metadata["run"]["controller"] == NAME
    # a tuned row needs tuned gains: the plug-in declares none
    proc = _wmr(site, "benchmark", "fig11", "--controllers", f"{NAME}-tuned", "--no-optimal",
                "--out", str(out))
    assert proc.returncode == 1
    assert proc.stderr.startswith(f"wmr: error: --controllers: {NAME} has no tuned gains")

    scenario = tmp_path / "short.toml"
    scenario.write_text('name = "short"\nstart = [0.0, 0.0, 0.0]\ngoal = [2.0, 1.0, 0.0]\n'
                        "max_time_s = 30.0\n", encoding="utf-8")
    proc = _wmr(site, "tune", str(scenario), "--controller", NAME, "--budget", "4",
                "--no-optimal", "--json")
    assert proc.returncode == 0, proc.stderr
    tuned = json.loads(proc.stdout.splitlines()[-1])
    assert set(tuned["gains"]) == {"k_v", "k_w"}  # the gains it declares with bounds
    assert tuned["start_gains"] == {"k_v": 0.5, "k_w": 2.0}
    assert tuned["objective_s"] <= tuned["start_objective_s"]


def test_a_broken_plugin_is_one_line_and_stops_nothing_else(site: Path, tmp_path: Path) -> None:
    proc = _wmr(site, "run", "--controller", "broken", "--out", str(tmp_path / "b.mcap"))
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("wmr: error: --controller: entry point broken = "
                                  "wmr_no_such_module:CONTROLLER of package "
                                  "wmr-broken-controller failed to load: "
                                  "ModuleNotFoundError")
    proc = _wmr(site, "run", "--controller", "lqr", "--out", str(tmp_path / "c.mcap"))
    assert proc.returncode == 1
    assert proc.stderr == ("wmr: error: --controller: unknown controller 'lqr' (one of: pi, "
                           f"astolfi, graceful, broken, {NAME})\n")
    # the paper's PI runs beside it (so did the example, in the tests above)
    proc = _wmr(site, "run", "--max-time", "0.5", "--out", str(tmp_path / "pi.mcap"))
    assert proc.returncode == 3, proc.stderr  # a timeout, as asked


def test_a_plugin_is_found_by_its_entry_point_and_built_from_a_run(on_path: Path) -> None:
    assert registry.names() == ("pi", "astolfi", "graceful", "broken", NAME)
    info = registry.get(NAME)
    assert [g.name for g in info.tunable()] == ["k_v", "k_w"]
    spec = RunSpec(name="t", start=Pose(0.0, 0.0, 0.0), goal=Pose(1.0, 1.0, 0.0),
                   controller=NAME, controller_gains=(("k_w", 3.0),))
    assert registry.check_gains(NAME, dict(spec.controller_gains)) == {
        "k_v": 0.5, "k_w": 3.0, "turn_tolerance_rad": 0.1}
    law = registry.make_controller(spec)
    sig = law.step(0.0, 0.0, 0.0, 0.0, 0.0)
    assert len(sig) == 20
    # turning in place towards the goal at 45 deg: k_w * pi/4, limited to 1.5 rad/s
    assert sig[LAW_SIGNALS.index("u_theta_radps")] == pytest.approx(min(3.0 * math.pi / 4, 1.5))
    assert sig[LAW_SIGNALS.index("u_s_mps")] == 0.0
    assert math.isnan(sig[LAW_SIGNALS.index("i_s_mps")])
    with pytest.raises(ConfigError, match=r"controller_gains.k_v: must be > 0"):
        RunSpec(name="t", start=Pose(0.0, 0.0, 0.0), goal=Pose(1.0, 1.0, 0.0),
                controller=NAME, controller_gains=(("k_v", -1.0),))
    with pytest.raises(ConfigError, match=r"controller_gains.k_rho: not a gain of "
                                          r"turn-then-drive \(allowed: k_v, k_w, "):
        registry.check_gains(NAME, {"k_rho": 1.0})


def test_the_api_runs_a_plugin_with_its_gains(on_path: Path, tmp_path: Path) -> None:
    slow = wmr.run(goal=(3.0, 0.0, 0.0), controller=NAME, out=tmp_path / "a.mcap")
    fast = wmr.run(goal=(3.0, 0.0, 0.0), controller=NAME, controller_gains={"k_v": 1.0},
                   out=tmp_path / "b.mcap")
    assert slow.record["status"] == fast.record["status"] == "converged"
    assert fast.log is not None and fast.log.metadata["run"]["controller_gains"] == {"k_v": 1.0}
    # straight ahead: no turn, the approach gain alone sets the pace
    assert fast.record["time_to_goal_s"] < slow.record["time_to_goal_s"]
    with pytest.raises(ConfigError, match=r"controller_gains.k_rho: not a gain of"):
        wmr.run(controller=NAME, controller_gains={"k_rho": 1.0}, out=tmp_path / "c.mcap")


def test_an_entry_point_that_is_not_a_controller_is_named(on_path: Path,
                                                          tmp_path: Path) -> None:
    (tmp_path / "wmr_odd.py").write_text(
        "from wmr_example_controller import CONTROLLER\n"
        "def not_a_controller():\n    return None\n", encoding="utf-8")
    _dist_info(tmp_path, "wmr-odd", "2.0", {registry.ENTRY_POINT_GROUP: {
        "odd": "wmr_odd:not_a_controller", "renamed": "wmr_odd:CONTROLLER",
        NAME: "wmr_odd:CONTROLLER"}})
    sys.path.insert(0, str(tmp_path))
    try:
        plugins.entry_points.cache_clear()
        with pytest.raises(ConfigError, match=r"controller: entry point odd = "
                           r"wmr_odd:not_a_controller of package wmr-odd is a function, not a "
                           r"wmr.core.control.registry.ControllerInfo"):
            registry.get("odd")
        with pytest.raises(ConfigError, match=r"declares a controller named 'turn-then-drive': "
                           "the entry point's name must be the same"):
            registry.get("renamed")
        with pytest.raises(ConfigError, match=r"controller 'turn-then-drive' is declared "
                           r"twice: entry point .* of package wmr-"):
            registry.get(NAME)
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("wmr_odd", None)


@pytest.mark.parametrize(("change", "problem"), [
    ({"signals": ("dr_m", "omega_r_ref_radps")}, "must fill omega_l_ref_radps"),
    ({"signals": ("tau_r_nm", "omega_r_ref_radps", "omega_l_ref_radps")}, "not distinct names"),
    ({"gains": (registry.Gain("k", 1.0, "1/s", (2.0, 5.0)),)}, "around its default"),
    ({"gains": (registry.Gain("k", -1.0, "1/s", (-0.5, -5.0)),)}, "must be (low, high)"),
    ({"name": "Turn Then"}, "use lower case letters"),
    ({"tuned": {"k": 1.0}}, "are not declared"),
])
def test_a_declaration_that_cannot_work_is_refused(change: dict[str, object],
                                                   problem: str) -> None:
    import dataclasses

    pi = registry.get("pi")
    fields = {"name": "x", "summary": "", "make": pi.make, **change}
    with pytest.raises(ValueError, match=problem.replace("(", r"\(").replace(")", r"\)")):
        dataclasses.replace(pi, **fields)  # type: ignore[arg-type]


def test_the_docs_show_the_example_as_it_is() -> None:
    """docs/plugins.md shows the example's pyproject.toml and module verbatim (and
    tests/test_docs_run.py runs the module's block): the page cannot drift from the package
    the tests install."""
    import re

    page = (_REPO / "docs" / "plugins.md").read_text(encoding="utf-8")
    blocks = re.findall(r"^```(\w*)\n(.*?)^```", page, flags=re.S | re.M)
    for path, lang in ((EXAMPLE / "pyproject.toml", "toml"),
                       (EXAMPLE / "wmr_example_controller" / "__init__.py", "python")):
        assert (lang, path.read_text(encoding="utf-8")) in blocks, path
    # what the page and this test say the example fills is what it declares
    module: dict[str, object] = {}
    exec((EXAMPLE / "wmr_example_controller" / "__init__.py").read_text(encoding="utf-8"), module)
    assert module["SIGNALS"] == EXAMPLE_SIGNALS

"""The controller as a batch dimension (issue 30): ``controller`` and ``controller_gains`` in
``[grid]`` and ``[[list]]``, common random numbers, the summary's ``controller`` and ``draw``."""

from __future__ import annotations

import csv
import math
import tomllib
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from wmr.apps.batch import BatchOptions, BatchSpec, load_batch, parse_batch, run_batch
from wmr.cli import main
from wmr.infra.errors import ConfigError

# a few short runs, starts 0.5-1.5 m from the goal, random robot and torque limit
BASE = """
name = "cmp"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 15.0
{head}
[random]
seed = 3
n = {n}
[random.start]
r_m = {{ dist = "uniform", low = 0.5, high = 1.5 }}
bearing_deg = {{ dist = "uniform", low = -180.0, high = 180.0 }}
[random.goal]
heading_deg = {{ dist = "along_x" }}
[random.params]
m = {{ dist = "normal", mean = 25.0, std = 3.0, low = 18.0, high = 32.0 }}
[random.limits]
torque_max_nm = {{ dist = "uniform", low = 6.0, high = 10.0 }}
"""

#: What a run's random draw decides: every one of these must be the same under every controller.
DRAWN = ("start.x_m", "start.y_m", "start.heading_deg", "goal.x_m", "goal.y_m",
         "goal.heading_deg", "start.r_m", "start.bearing_deg", "params.m", "limits.torque_max_nm")


def _parse(text: str) -> BatchSpec:
    return parse_batch(tomllib.loads(text))


def _by_draw(batch: BatchSpec) -> dict[tuple[int, str, float], dict[str, float | str]]:
    """The drawn inputs of each run, by (draw, controller, K_ps)."""
    out: dict[tuple[int, str, float], dict[str, float | str]] = {}
    for run in batch.runs:
        key = (run.draw, run.controller, run.spec.gains.K_ps)
        assert key not in out, f"two runs of {key}"
        out[key] = {c: run.inputs[c] for c in DRAWN}
    return out


def test_the_same_draw_gets_the_same_inputs_under_every_controller() -> None:
    """Common random numbers: draw d has the inputs of draw d of the spec without a controller
    dimension, under each controller, whatever the place of the controller among the axes."""
    alone = _parse(BASE.format(head="", n=6))
    gains = "[grid.gains]\nK_ps = [0.5, 0.8]\n"
    first = _parse(BASE.format(head="", n=6)
                   + '[grid]\ncontroller = ["pi", "astolfi", "graceful"]\n' + gains)
    last = _parse(BASE.format(head="", n=6) + gains
                  + '[grid]\ncontroller = ["graceful", "astolfi", "pi"]\n')
    listed = _parse(BASE.format(head="", n=6)
                    + '[[list]]\nname = "pi"\n[[list]]\nname = "ast"\ncontroller = "astolfi"\n')
    assert len(first.runs) == len(last.runs) == 36 and len(listed.runs) == 12
    reference = {run.draw: {c: run.inputs[c] for c in DRAWN} for run in alone.runs}
    assert len(reference) == 6 and len({r["params.m"] for r in reference.values()}) == 6
    for batch, controllers in ((first, ("pi", "astolfi", "graceful")),
                               (last, ("pi", "astolfi", "graceful")),
                               (listed, ("pi", "astolfi"))):
        drawn = _by_draw(batch)
        assert {c for _, c, _ in drawn} == set(controllers)
        for (draw, _, _), inputs in drawn.items():
            assert inputs == reference[draw]
    # the runs' own specs agree too, not only the summary's columns
    for run in first.runs:
        twin = alone.runs[run.draw].spec
        assert (run.spec.start, run.spec.goal, run.spec.params, run.spec.limits) == \
            (twin.start, twin.goal, twin.params, twin.limits)


def test_controller_in_grid_and_list_makes_its_runs() -> None:
    grid = _parse(BASE.format(head="", n=2) + '[grid]\ncontroller = ["pi", "astolfi"]\n')
    assert [(r.controller, r.draw) for r in grid.runs] == \
        [("pi", 0), ("pi", 1), ("astolfi", 0), ("astolfi", 1)]
    # the name (and so the run's id) says the controller when it varies
    assert [r.name for r in grid.runs] == ["cmp-pi-0000", "cmp-pi-0001", "cmp-astolfi-0002",
                                           "cmp-astolfi-0003"]
    assert "controller" not in grid.input_columns  # a column of its own, not an input
    listed = _parse(BASE.format(head="", n=2) + '[[list]]\nname = "pi"\n'
                    '[[list]]\nname = "fast-astolfi"\ncontroller = "astolfi"\n'
                    "controller_gains = { astolfi = { k_rho = 4.0, k_alpha = 10.0 } }\n"
                    '[[list]]\nname = "graceful"\ncontroller = "graceful"\n')
    runs = list(listed.runs)
    assert [(r.controller, r.variant) for r in runs] == [
        ("pi", "pi"), ("pi", "pi"), ("astolfi", "fast-astolfi"), ("astolfi", "fast-astolfi"),
        ("graceful", "graceful"), ("graceful", "graceful")]
    assert runs[2].name == "cmp-fast-astolfi-astolfi-0002" and runs[4].name == "cmp-graceful-0004"
    assert dict(runs[2].spec.controller_gains) == {"k_rho": 4.0, "k_alpha": 10.0}
    assert runs[4].spec.controller_gains == () and runs[0].spec.controller_gains == ()
    # the gains' columns: each run's own controller's gains, its defaults included; none for
    # the others
    assert runs[2].inputs["controller_gains.astolfi.k_rho"] == 4.0
    assert math.isnan(runs[0].inputs["controller_gains.astolfi.k_rho"])
    assert math.isnan(runs[4].inputs["controller_gains.astolfi.k_alpha"])
    # a grid of one controller's gains, in a spec of that controller
    gains = _parse(BASE.format(head='controller = "astolfi"', n=1)
                   + "[grid.controller_gains.astolfi]\nk_rho = [2.0, 3.0]\n")
    assert [dict(r.spec.controller_gains) for r in gains.runs] == [{"k_rho": 2.0},
                                                                    {"k_rho": 3.0}]
    assert [r.inputs["controller_gains.astolfi.k_rho"] for r in gains.runs] == [2.0, 3.0]


def test_a_spec_without_a_controller_dimension_keeps_its_names_and_ids() -> None:
    """The name gets the controller only when the controller varies: a spec of one controller
    (the scenario's, here Astolfi) expands as before, the same names and ids."""
    text = BASE.format(head='controller = "astolfi"', n=3)
    batch = _parse(text)
    assert [r.name for r in batch.runs] == ["cmp-0000", "cmp-0001", "cmp-0002"]
    assert {r.controller for r in batch.runs} == {"astolfi"}
    same = _parse(text + '[grid]\ncontroller = ["astolfi"]\n')  # varied, one value
    assert [r.draw for r in same.runs] == [0, 1, 2]


@pytest.mark.parametrize(("extra", "field", "words"), [
    ('[grid]\ncontroller = ["pi", "astolfy"]\n', "grid.controller[1]",
     ("unknown controller 'astolfy'", "pi, astolfi, graceful")),
    ('[[list]]\ncontroller = "lqr"\n', "list[0].controller", ("unknown controller 'lqr'",)),
    ('[[list]]\ncontroller = 3\n', "list[0].controller", ("unknown controller 3",)),
    ('[[list]]\ncontroller = "astolfi"\ncontroller_gains = { astolfi = { k_r = 4.0 } }\n',
     "list[0].controller_gains.astolfi.k_r",
     ("not a gain of astolfi", "k_rho, k_alpha, k_beta")),
    ('[grid]\ncontroller = ["pi", "graceful"]\n[grid.controller_gains.graceful]\n'
     "k_rho = [1.0]\n", "grid.controller_gains.graceful.k_rho",
     ("not a gain of graceful", "k_phi")),
    ('[[list]]\ncontroller_gains = { pi = { K_ps = 1.0 } }\n', "list[0].controller_gains.pi",
     ("the PI takes its gains from [gains]",)),
    ('[[list]]\ncontroller_gains = { lqr = { k = 1.0 } }\n', "list[0].controller_gains.lqr",
     ("unknown controller 'lqr'",)),
    ('[[list]]\ncontroller = "astolfi"\n[[list]]\n'
     "controller_gains = { graceful = { k_phi = 1.0 } }\n", "list[1].controller_gains.graceful",
     ("which no run uses", "astolfi, pi")),
    ('[[list]]\ncontroller = "astolfi"\ncontroller_gains = { astolfi = { k_rho = -1.0 } }\n',
     "list[0].controller_gains.astolfi", ("violate the stability condition", "(run 0,")),
    ('[grid]\ncontroller = ["pi", "astolfi"]\n[grid.controller_gains.astolfi]\n'
     "k_rho = [2.0, 3.0]\n", "grid.controller_gains.astolfi.k_rho",
     ("repeats every run of the others", "[[list]] entry")),
])
def test_an_unknown_controller_or_gain_is_one_line_naming_the_field(
        extra: str, field: str, words: tuple[str, ...], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError) as err:
        _parse(BASE.format(head="", n=2) + extra)
    assert err.value.field == field
    assert all(w in str(err.value) for w in words), str(err.value)
    spec = tmp_path / "spec.toml"
    spec.write_text(BASE.format(head="", n=2) + extra, encoding="utf-8")
    assert main(["batch", str(spec), "--check"]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"wmr: error: {field}: "), lines


def test_a_controller_is_not_drawn_at_random() -> None:
    for key, value in (("controller", '{ dist = "choice", values = [1.0] }'),
                       ("controller_gains", "{ astolfi = { k_rho = 1.0 } }")):
        text = BASE.format(head="", n=2).replace("[random.start]",
                                                 f"{key} = {value}\n[random.start]")
        with pytest.raises(ConfigError) as err:
            _parse(text)
        assert err.value.field == f"random.{key}" and "[grid] or [[list]]" in err.value.fix


def test_a_batch_of_pi_and_astolfi_on_the_same_draws(fmu3: Path, tmp_path: Path) -> None:
    """A real batch: 3 draws under PI and Astolfi.  The summary (Parquet and CSV) has the
    controller and the draw of each run; runs of one draw had the same inputs and, the
    controllers differing, not the same result; resumed, the summary is the same bytes (its
    rows then come from the journal)."""
    spec = tmp_path / "cmp.toml"
    spec.write_text(BASE.format(head="", n=3) + '[grid]\ncontroller = ["pi", "astolfi"]\n',
                    encoding="utf-8")
    out = tmp_path / "out"
    result = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3),
                       progress=False)
    assert len(result.executed) == 6 and result.counts["converged"] == 6
    table = pq.read_table(out / "summary.parquet").to_pylist()
    assert [(r["controller"], r["draw"]) for r in table] == [
        ("pi", 0), ("pi", 1), ("pi", 2), ("astolfi", 0), ("astolfi", 1), ("astolfi", 2)]
    for pi, ast in zip(table[:3], table[3:], strict=True):
        assert {c: pi[c] for c in DRAWN} == {c: ast[c] for c in DRAWN}
        assert pi["time_to_goal_s"] != ast["time_to_goal_s"]
    # docs/batch.md's pairing, as written there
    s = pd.read_parquet(out / "summary.parquet")
    t = s.pivot(index="draw", columns="controller", values="time_to_goal_s")
    assert list(t.index) == [0, 1, 2] and sorted(t.columns) == ["astolfi", "pi"]
    assert list(t["astolfi"] / t["pi"]) == [a["time_to_goal_s"] / p["time_to_goal_s"]
                                            for p, a in zip(table[:3], table[3:], strict=True)]
    with (out / "summary.csv").open(encoding="utf-8", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["controller"], r["draw"]) for r in rows] == [
        (r["controller"], str(r["draw"])) for r in table]
    before = (out / "summary.csv").read_bytes(), (out / "summary.parquet").read_bytes()
    again = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.executed == [] and again.skipped == 6
    assert ((out / "summary.csv").read_bytes(), (out / "summary.parquet").read_bytes()) == before


def test_the_summary_names_the_controller_when_it_is_not_varied(fmu3: Path,
                                                                tmp_path: Path) -> None:
    spec = tmp_path / "one.toml"
    spec.write_text(BASE.format(head='controller = "astolfi"', n=2), encoding="utf-8")
    run_batch(load_batch(spec), tmp_path / "out", BatchOptions(workers=1, fmu_path=fmu3),
              progress=False)
    table = pq.read_table(tmp_path / "out" / "summary.parquet")
    assert table.column("controller").to_pylist() == ["astolfi", "astolfi"]
    assert table.column("draw").to_pylist() == [0, 1]


def test_a_controller_fmu_spec_cannot_vary_the_controller() -> None:
    """The controller FMU is the PI: a peer in the grid is refused, naming the grid's field."""
    text = BASE.format(head="controller_fmu = true", n=2)
    assert {r.controller for r in _parse(text + '[grid]\ncontroller = ["pi"]\n').runs} == {"pi"}
    with pytest.raises(ConfigError) as err:
        _parse(text + '[grid]\ncontroller = ["pi", "astolfi"]\n')
    assert err.value.field == "grid.controller"
    assert "controller FMU is the PI" in str(err.value) and "(run 2," in str(err.value)

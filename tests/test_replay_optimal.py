"""``wmr replay DIR --worst N`` draws each chosen run's optimal path beside it when the batch
has the optimum (a spec's ``optimal``), and none when it has not: read back from the ``.rrd``
with Rerun's own reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import rerun.chunk as rrc

from wmr.adapters.rerun.replay import OPTIMAL_ENTITY, run_entity
from wmr.apps.batch import BatchOptions, load_batch, run_batch
from wmr.apps.batch.rerun import pick_runs
from wmr.apps.run import LogPolicy
from wmr.cli import main

# three short rest-to-rest runs (each about a second to solve), the worst two replayed
SPEC = """name = "ro"
start = [2.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 30.0
optimal = "time"
[[list]]
name = "light"
params = { m = 20.0 }
[[list]]
name = "heavy"
params = { m = 40.0 }
[[list]]
name = "side"
start = [1.0, 1.5, 90.0]
"""


def _entities(rrd: Path) -> dict[str, dict[str, list[object]]]:
    """Per entity path of the recording: its components' first rows."""
    reader = rrc.RrdReader(rrd)
    [store] = reader.recordings()
    out: dict[str, dict[str, list[object]]] = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        comps = out.setdefault(chunk.entity_path, {})
        for name in batch.schema.names:
            if ":" in name:
                comps[name] = batch.column(name).to_pylist()[0]
    return out


@pytest.mark.parametrize("optimal", [True, False])
def test_replay_worst_draws_the_optimal_path_beside_each_run_when_the_batch_has_it(
        fmu3: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], optimal: bool) -> None:
    spec = tmp_path / "ro.toml"
    spec.write_text(SPEC if optimal else SPEC.replace('optimal = "time"\n', ""),
                    encoding="utf-8")
    out = tmp_path / "batch"
    run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3, log=LogPolicy("full")),
              progress=False)
    rrd = tmp_path / "worst.rrd"
    assert main(["replay", str(out), "--worst", "2", "--no-viewer", "--rrd", str(rrd)]) == 0
    capsys.readouterr()
    ents = _entities(rrd)
    drawn = sorted(e for e in ents if e.endswith("/" + OPTIMAL_ENTITY))
    if not optimal:
        assert drawn == []
        return
    rows = {r["run_id"]: r for r in pq.read_table(out / "summary.parquet").to_pylist()}
    chosen = [rows[run_id] for run_id, _ in pick_runs(out, worst=2)]
    assert drawn == sorted(f"/{run_entity(Path(r['mcap']).stem)}/{OPTIMAL_ENTITY}"
                           for r in chosen)
    for r in chosen:
        root = f"/{run_entity(Path(r['mcap']).stem)}"
        comps = ents[f"{root}/{OPTIMAL_ENTITY}"]
        assert comps["LineStrips2D:labels"] == ["optimal"]
        [strip] = comps["LineStrips2D:strips"]
        path = np.array(strip)
        # from the run's start to its goal (the OCP's own, not another run's)
        assert path[0] == pytest.approx([r["start.x_m"], r["start.y_m"]], abs=1e-6)
        assert path[-1] == pytest.approx([r["goal.x_m"], r["goal.y_m"]], abs=1e-3)
        # the run's colour family: a lighter tint of its own path's colour, thinner
        [own] = ents[f"{root}/world/path"]["LineStrips2D:colors"]
        [light] = comps["LineStrips2D:colors"]
        own_rgb = [(own >> s) & 0xFF for s in (24, 16, 8)]  # packed RGBA
        light_rgb = [(light >> s) & 0xFF for s in (24, 16, 8)]
        assert light_rgb != own_rgb and all(a >= b for a, b in zip(light_rgb, own_rgb,
                                                                  strict=True))

"""Rerun without our replay (issue 11, item 5): the blueprint's field mappings name exactly the
struct components and fields that Rerun's own MCAP loader makes of a log, on a duration
(simulation time) timeline."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest
import rerun.chunk as rrc

from wmr.adapters.rerun.blueprint import signal_mappings
from wmr.cli import main


def test_the_blueprint_maps_every_field_rerun_loads(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "run.mcap"
    assert main(["run", "--max-time", "1", "--out", str(log)]) == 3  # a timeout, logged
    components: dict[str, dict[str, pa.DataType]] = {}
    time_types: set[str] = set()
    for chunk in rrc.McapReader(log, timeline_type="duration_ns").stream():
        schema = chunk.to_record_batch().schema
        for f in schema:
            if f.name.endswith(":message"):
                components.setdefault(chunk.entity_path, {})[f.name] = f.type
            if f.name == "message_log_time":
                time_types.add(str(f.type))
    assert time_types == {"duration[ns]"}  # simulation time, not dates in 1970
    mappings = signal_mappings()
    # open-loop logs hold /robot/torques, runs with sensors the covariance
    closed_loop = {t: m for t, m in mappings.items()
                   if t not in ("/robot/torques", "/robot/pose_estimate/covariance")}
    assert "/controller/phase" in closed_loop
    assert set(closed_loop) <= set(components)
    for topic, pairs in closed_loop.items():
        for component, selector in pairs:
            struct = components[topic][component].value_type  # list<struct<...>>
            assert selector[1:] in {struct.field(i).name for i in range(struct.num_fields)}

    rbl = tmp_path / "wmr.rbl"
    capsys.readouterr()
    assert main(["replay", "--blueprint", str(rbl)]) == 0
    assert capsys.readouterr().out.strip() == str(rbl)
    assert rbl.stat().st_size > 1000

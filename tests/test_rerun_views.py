"""What a user sees, checked with Rerun's own tools (``rerun mcap convert``, ``rerun rrd
print`` and Rerun's .rrd reader), not ours: the raw log's scene entities and their
archetypes on a duration timeline, the blueprints' views, and the replay's dashboard."""

from __future__ import annotations

import re
import socket
import subprocess
from collections import defaultdict
from pathlib import Path
from typing import Any

import pyarrow as pa
import pytest
import rerun.chunk as rrc
import rerun_cli

from wmr.adapters.mcap import read_run
from wmr.adapters.mcap.scene import control_phases
from wmr.adapters.rerun.blueprint import APPLICATION_ID, LOG_TIMELINE
from wmr.adapters.rerun.replay import PANELS, TIMELINE
from wmr.cli import main

RERUN = str(Path(rerun_cli.__file__).parent / "rerun")
_CHUNK = re.compile(r"with (\d+) rows .* - (\S+) - data columns: \[(.*)\]")


def rrd_print(path: Path) -> dict[str, tuple[int, set[str]]]:
    """``rerun rrd print``: per entity, its rows and components (first recording only)."""
    text = subprocess.run([RERUN, "rrd", "print", str(path)], capture_output=True, text=True,
                          check=True).stdout
    out: dict[str, tuple[int, set[str]]] = {}
    for m in _CHUNK.finditer(text):
        rows, comps = out.get(m[2], (0, set()))
        new = set(m[3].split())
        out[m[2]] = (rows + (int(m[1]) if not any("Mcap" in c for c in new) else 0),
                     comps | new)
    return out


def blueprint(path: Path) -> tuple[str, dict[str, dict[str, Any]]]:
    """The application id of the blueprint in ``path`` and its entities' components."""
    reader = rrc.RrdReader(path)
    [store] = reader.blueprints()
    ents: dict[str, dict[str, Any]] = defaultdict(dict)
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if ":" in name:
                ents[chunk.entity_path][name] = batch.column(name).to_pylist()[0]
    return store.application_id, ents


def views(ents: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Per view: class, name, origin, and the components of its sub-entities."""
    out = []
    for path, comps in ents.items():
        if "ViewBlueprint:class_identifier" in comps:
            sub = {k: v for p, c in ents.items() if p.startswith(path + "/")
                   for k, v in c.items()}
            out.append({"class": comps["ViewBlueprint:class_identifier"][0],
                        "name": comps["ViewBlueprint:display_name"][0],
                        "origin": comps["ViewBlueprint:space_origin"][0], **sub})
    return out


def column_values(path: Path, entity: str, column: str) -> set[str]:
    """Every value of ``column`` (a list of strings per row) on ``entity`` in an .rrd."""
    out: set[str] = set()
    for chunk in rrc.RrdReader(path).stream():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            if column in batch.schema.names:
                out |= {v for row in batch.column(column).to_pylist() if row for v in row}
    return out


def timeline_types(path: Path) -> dict[str, str]:
    types: dict[str, str] = {}
    for chunk in rrc.RrdReader(path).stream():
        for f in chunk.to_record_batch().schema:
            if pa.types.is_duration(f.type) or pa.types.is_timestamp(f.type):
                types[f.name] = str(f.type)
    return types


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("views")
    out = {"fig11": folder / "fig11.mcap", "gps": folder / "gps.mcap",
           "near": folder / "near.mcap"}
    assert main(["run", "--out", str(out["fig11"])]) == 0
    assert main(["run", "--sensors", "gps", "--max-time", "5", "--out", str(out["gps"])]) == 3
    assert main(["run", "--start", "17", "8", "90", "--gain", "K_ps=0.8", "--out",
                 str(out["near"])]) == 0
    return out


def test_raw_log_draws_itself_on_a_duration_timeline(logs: dict[str, Path],
                                                     tmp_path: Path) -> None:
    """``rerun mcap convert``: the robot (points in frame ``base_link``, once per control phase,
    placed by the ``/tf`` transforms from ``world`` to ``base_link``), its path and the goal
    are Points3D; the fixes and the estimate too for a run with sensors; the phase is a
    plottable message; the log time is a duration."""
    run = read_run(logs["fig11"])
    rrd = tmp_path / "raw.rrd"
    subprocess.run([RERUN, "mcap", "convert", str(logs["fig11"]), "--timeline-type", "duration",
                    "--application-id", APPLICATION_ID, "-o", str(rrd)], check=True,
                   capture_output=True)
    ents = rrd_print(rrd)
    points = {"Points3D:positions", "Points3D:colors"}
    rows, comps = ents["/scene/robot"]
    assert points | {"InstancePoses3D:translations", "CoordinateFrame:frame"} <= comps
    phase = control_phases(run.signals["dr_m"], float(run.metadata["run"]["stop_radius_m"]))
    assert rows == 1 + int((phase[1:] != phase[:-1]).sum()) == 2  # approach, then align
    tf_rows, tf_comps = ents["/tf"]
    assert {"Transform3D:translation", "Transform3D:quaternion", "Transform3D:parent_frame",
            "Transform3D:child_frame"} <= tf_comps and tf_rows == len(run.t_ns)
    # the robot's frame is the one the transforms move: Rerun draws it where /tf puts it
    assert column_values(rrd, "/scene/robot", "CoordinateFrame:frame") == {"base_link"}
    assert column_values(rrd, "/tf", "Transform3D:child_frame") == {"base_link"}
    assert column_values(rrd, "/tf", "Transform3D:parent_frame") == {"world"}
    assert column_values(rrd, "/scene/path", "CoordinateFrame:frame") == {"world"}
    for topic in ("/scene/path", "/scene/goal"):
        assert points <= ents[topic][1] and ents[topic][0] == 1, topic
    assert "wmr.ControlPhase:message" in ents["/controller/phase"][1]
    assert timeline_types(rrd)[LOG_TIMELINE] == "duration[ns]"

    gps = tmp_path / "gps.rrd"
    subprocess.run([RERUN, "mcap", "convert", str(logs["gps"]), "--timeline-type", "duration",
                    "-o", str(gps)], check=True, capture_output=True)
    ents = rrd_print(gps)
    for topic in ("/scene/gps", "/scene/estimate"):
        assert points <= ents[topic][1], topic


def test_raw_blueprint_views_name_what_the_loader_makes(logs: dict[str, Path],
                                                        tmp_path: Path) -> None:
    """The blueprint applies (its application id is the converted recording's), looks down on
    the scene entities, and every time series view plots topics the log holds (the sensing
    and open-loop panels aside); the time panel is on the log time."""
    rbl = tmp_path / "wmr.rbl"
    assert main(["replay", "--blueprint", str(rbl), str(logs["fig11"])]) == 0
    assert not logs["fig11"].with_suffix(".rrd").exists()  # a blueprint only: no replay
    app, ents = blueprint(rbl)
    assert app == APPLICATION_ID
    assert ents["/time_panel"]["TimePanelBlueprint:timeline"] == [LOG_TIMELINE]
    assert ents["/blueprint_panel"]["PanelBlueprint:state"] == [2]  # collapsed
    vs = views(ents)
    [scene] = [v for v in vs if v["class"] == "3D"]
    assert any("/scene/**" in q for q in scene["ViewContents:query"])
    eye = scene["EyeControls3D:position"][0]
    assert eye[2] > 20 and 0 < eye[0] < 20 and 0 < eye[1] < 10  # above the fig11 run
    rrd = tmp_path / "raw.rrd"
    subprocess.run([RERUN, "mcap", "convert", str(logs["fig11"]), "--timeline-type", "duration",
                    "-o", str(rrd)], check=True, capture_output=True)
    held = set(rrd_print(rrd))
    plots = [v for v in vs if v["class"] == "TimeSeries"]
    assert len(plots) == 7  # no covariance panel for a run without sensors: it stays empty
    for v in plots:
        topics = {q.split()[-1] for q in v["ViewContents:query"]}
        assert topics - {"/robot/torques"} <= held, v["name"]  # open-loop logs: the torques
    # a run with sensors: its covariance too, on the topic Rerun makes of it
    assert main(["replay", "--blueprint", str(rbl), str(logs["gps"])]) == 0
    _, ents = blueprint(rbl)
    [cov] = [v for v in views(ents) if "covariance" in v["name"]]
    assert {q.split()[-1] for q in cov["ViewContents:query"]} == {
        "/robot/pose_estimate/covariance"}
    subprocess.run([RERUN, "mcap", "convert", str(logs["gps"]), "--timeline-type", "duration",
                    "-o", str(rrd)], check=True, capture_output=True)
    assert "wmr.PoseCovariance:message" in rrd_print(rrd)["/robot/pose_estimate/covariance"][1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_raw_log_opened_directly_takes_the_blueprint_beside_it(logs: dict[str, Path],
                                                               tmp_path: Path) -> None:
    """``rerun X.mcap X.rbl``, as the viewer imports it (``--save`` keeps what it received):
    the blueprint ``--blueprint-for`` wrote is for the application Rerun makes of the file
    (its name has a dot, which Rerun changes), on a timeline of Rerun's own MCAP import (the
    loader ``rerun mcap convert`` runs, with the viewer's defaults), looking down on the scene
    entities that draw."""
    log = tmp_path / "fig11.v2.mcap"
    log.write_bytes(logs["fig11"].read_bytes())
    assert main(["replay", "--blueprint-for", str(log)]) == 0
    rbl = log.with_suffix(".rbl")
    # each file as the viewer imports it, one viewer each: given both, `rerun --save` ends
    # with the first source to end (the small .rbl), cutting the log's stream anywhere, even
    # before its store info (2 in 20 saves held no recording; the others 6 to 44 of its 182
    # chunks); one file to a viewer, the save holds all of it (25 in 25)
    received: dict[Path, rrc.RrdReader] = {}
    for path in (log, rbl):
        saved = tmp_path / f"direct-{path.suffix[1:]}.rrd"
        subprocess.run([RERUN, str(path), "--port", str(_free_port()), "--save", str(saved)],
                       check=True, capture_output=True, timeout=120)
        received[path] = rrc.RrdReader(saved)
    [recording], [bp] = received[log].recordings(), received[rbl].blueprints()
    assert bp.application_id == recording.application_id  # the viewer applies it
    app, ents = blueprint(rbl)
    assert app == recording.application_id
    rrd = tmp_path / "imported.rrd"
    subprocess.run([RERUN, "mcap", "convert", str(log), "-o", str(rrd)], check=True,
                   capture_output=True)
    [converted] = rrc.RrdReader(rrd).recordings()
    # the viewer received the whole log: every row the converter makes of it
    assert sum(c.num_rows for c in received[log].stream(store=recording)) == sum(
        c.num_rows for c in rrc.RrdReader(rrd).stream(store=converted))
    [timeline] = ents["/time_panel"]["TimePanelBlueprint:timeline"]
    assert timeline_types(rrd)[timeline] == "timestamp[ns]"  # dates: see docs/replay.md
    [scene] = [v for v in views(ents) if v["class"] == "3D"]
    assert any("/scene/**" in q for q in scene["ViewContents:query"])
    assert {"Points3D:positions", "InstancePoses3D:translations"} <= rrd_print(rrd)[
        "/scene/robot"][1]


def test_replay_is_a_dashboard(logs: dict[str, Path], tmp_path: Path) -> None:
    """One run: a 2-D world view with fixed bounds around the start and the goal, one plot per
    panel and the phase, the summary document, side panels collapsed, a duration timeline."""
    rrd = tmp_path / "one.rrd"
    assert main(["replay", str(logs["fig11"]), "--rrd", str(rrd)]) == 0
    _, ents = blueprint(rrd)
    vs = views(ents)
    [world] = [v for v in vs if v["class"] == "2D"]
    bounds = world["VisualBounds2D:range"][0]
    x0, x1 = bounds["x_range"]
    y0, y1 = bounds["y_range"]  # the view's y points down: the world's y is mirrored
    assert x0 < 0.0 < 20.0 < x1 and y0 < -10.0 < 0.0 < y1
    assert any("/grid/**" in q for q in world["ViewContents:query"])
    names = {v["name"] for v in vs if v["class"] == "TimeSeries"}
    assert {p.title for p in PANELS} <= names and any("phase" in n for n in names)
    [doc] = [v for v in vs if v["class"] == "TextDocument"]
    assert doc["origin"] == "/summary"
    for panel in ("/blueprint_panel", "/selection_panel"):
        assert ents[panel]["PanelBlueprint:state"] == [2]
    assert timeline_types(rrd)[TIMELINE] == "duration[ns]"
    text = rrd_print(rrd)
    assert "TextDocument:text" in text["/summary"][1]
    assert {"LineStrips2D:strips"} <= text["/grid/lines"][1]

    # two runs: no legend (the run's colour and number name it), overlay titles
    both = tmp_path / "two.rrd"
    assert main(["replay", str(logs["fig11"]), str(logs["near"]), "--rrd", str(both)]) == 0
    _, ents = blueprint(both)
    plots = [v for v in views(ents) if v["class"] == "TimeSeries"]
    assert plots and all(v["PlotLegend:visible"] == [False] for v in plots)
    assert {p.overlay_title for p in PANELS} <= {v["name"] for v in plots}
    docs = [e for e, (_, c) in rrd_print(both).items() if "TextDocument:text" in c]
    assert docs == ["/summary"]

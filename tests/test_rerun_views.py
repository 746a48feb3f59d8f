"""What a user sees, checked with Rerun's own tools (``rerun mcap convert``, ``rerun rrd
print`` and Rerun's .rrd reader), not ours: the raw log's scene entities and their
archetypes on a duration timeline, the blueprints' views, and the replay's dashboard."""

from __future__ import annotations

import math
import re
import socket
import subprocess
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
import rerun.chunk as rrc
import rerun_cli

from wmr.adapters.mcap import read_run
from wmr.adapters.mcap.scene import PHASE_COLORS, control_phases
from wmr.adapters.mcap.sensing import read_sensing
from wmr.adapters.rerun.blueprint import APPLICATION_ID, LOG_TIMELINE
from wmr.adapters.rerun.replay import (
    HEADING_COLORS,
    MIN_SERIES_LUMINANCE,
    PANELS,
    TIMELINE,
    Y_INTERVALS,
    relative_luminance,
    run_color,
)
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
    are Points3D; the fixes (all at t = 0, and each at its time) and the
    estimate too for a run with sensors; the phase is a
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
    # each fix a point of its own at its arrival (issue 33, item 11; it was a pose, not drawn)
    fixes = read_sensing(logs["gps"])
    assert fixes is not None
    assert points <= ents["/sensors/gps"][1] and ents["/sensors/gps"][0] == len(fixes.gps_t_ns)


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
    assert {p.title for p in PANELS} <= names and any("phase" in n.lower() for n in names)
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


# -- issue 33: every plot readable ------------------------------------------------------------


def _plots(rrd: Path) -> list[dict[str, Any]]:
    _, ents = blueprint(rrd)
    return [v for v in views(ents) if v["class"] == "TimeSeries"]


def _labelled(lo: float, hi: float) -> int:
    """How many values Rerun labels on a y axis ``[lo, hi]``: the multiples of the smallest
    power of ten of which the range holds at most Y_INTERVALS + 1.5 (egui_plot labels powers
    of ten only, each at least 29 points apart in a 250-point plot)."""
    step = 10.0 ** math.floor(math.log10((hi - lo) / Y_INTERVALS))
    while (hi - lo) / step > Y_INTERVALS + 1.5:
        step *= 10.0
    return math.floor(hi / step) - math.ceil(lo / step) + 1


def test_every_plot_has_a_labelled_y_range(logs: dict[str, Path], tmp_path: Path) -> None:
    """Item 1: each plot of the replay (one run, one with sensors, several runs) has a fixed
    y range holding its lines and at least two values Rerun labels (before: the batch's u_s,
    u_theta and tau_r showed only "0", the estimate error nothing but "0"); and the layout
    is three plots to a row, none left empty (the sensing panel has the phase behind it)."""
    for name, inputs in (("one", [logs["fig11"]]), ("gps", [logs["gps"]]),
                         ("two", [logs["fig11"], logs["near"]])):
        rrd = tmp_path / f"{name}.rrd"
        assert main(["replay", *map(str, inputs), "--rrd", str(rrd)]) == 0
        plots = _plots(rrd)
        assert len(plots) == 9 + (name == "gps")
        for v in plots:
            lo, hi = v["ScalarAxis:range"][0]
            assert _labelled(lo, hi) >= 2, (name, v["name"], lo, hi)
        _, ents = blueprint(rrd)
        grids = [c for c in ents.values() if c.get("ContainerBlueprint:container_kind") == [4]]
        [grid] = grids
        assert grid["ContainerBlueprint:grid_columns"] == [3]
        assert len(grid["ContainerBlueprint:contents"]) == 9
    # the lines are inside: Δr of the fig11 run from 22.4 m to 0
    one = {v["name"]: v["ScalarAxis:range"][0] for v in _plots(tmp_path / "one.rrd")}
    lo, hi = one[PANELS[0].title]
    run = read_run(logs["fig11"])
    assert lo <= 0.0 and hi >= float(run.signals["dr_m"].max())


def test_plot_lines_read_on_the_dark_theme(logs: dict[str, Path], tmp_path: Path) -> None:
    """Item 8: every line colour of every plot (per signal, per run up to 60 runs) has a
    relative luminance of at least 0.1 (before: u_s navy 0.03, u_theta maroon 0.03)."""
    rrd = tmp_path / "one.rrd"
    assert main(["replay", str(logs["gps"]), "--rrd", str(rrd)]) == 0
    colors = []
    for chunk in rrc.RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        for name in ("SeriesLines:colors", "SeriesPoints:colors"):
            if name in batch.schema.names:
                colors += [c for row in batch.column(name).to_pylist() for c in row]
    assert len(colors) >= sum(len(p.series) for p in PANELS)
    for rgba in colors:
        rgb = ((rgba >> 24) & 255, (rgba >> 16) & 255, (rgba >> 8) & 255)
        assert relative_luminance(rgb) >= MIN_SERIES_LUMINANCE, rgb
    for n in (5, 60):
        assert min(relative_luminance(run_color(k, n)) for k in range(n)) >= 0.1


def test_world_frames_d_and_r_and_the_heading_stands_out(logs: dict[str, Path],
                                                         tmp_path: Path) -> None:
    """Items 4, 5, 6: the fixed world frame holds D and R at every step (before: their lines
    ran off the view); the heading arrow is dark on either phase's path colour, longer than
    the body, wider than the path; D's and R's labels are apart from each other."""
    rrd = tmp_path / "one.rrd"
    assert main(["replay", str(logs["fig11"]), "--rrd", str(rrd)]) == 0
    _, ents = blueprint(rrd)
    [world] = [v for v in views(ents) if v["class"] == "2D"]
    b = world["VisualBounds2D:range"][0]
    (x0, x1), (y0, y1) = b["x_range"], b["y_range"]
    run = read_run(logs["fig11"])
    for px, py in (("D_x_m", "D_y_m"), ("R_x_m", "R_y_m")):
        x, y = run.signals[px], -run.signals[py]  # the view's y points down
        assert (x0 <= x.min()) and (x.max() <= x1) and (y0 <= y.min()) and (y.max() <= y1)
    for path_rgb in PHASE_COLORS:
        for arrow_rgb in HEADING_COLORS:  # WCAG contrast ratio of the arrow on the path
            hi, lo = sorted((relative_luminance(path_rgb), relative_luminance(arrow_rgb)))[::-1]
            assert (hi + 0.05) / (lo + 0.05) >= 3.0
    text = rrd_print(rrd)
    assert {"Points2D:positions", "Points2D:labels"} <= text["/runs/fig11/world/D_label"][1]
    reader = rrc.RrdReader(rrd)
    got: dict[str, Any] = {}
    for chunk in reader.stream():
        if chunk.entity_path in ("/runs/fig11/world/D_label", "/runs/fig11/world/R_label"):
            batch = chunk.to_record_batch()
            if "Points2D:positions" in batch.schema.names:
                got[chunk.entity_path] = np.array(
                    [r[0] for r in batch.column("Points2D:positions").to_pylist()])
    d_lab, r_lab = got["/runs/fig11/world/D_label"], got["/runs/fig11/world/R_label"]
    gap = np.hypot(*(d_lab - r_lab).T)
    assert gap.min() > 0.02 * (x1 - x0)  # at least one label height apart, even where D = R


def test_summaries_show_the_robot_and_the_varied_inputs_first(logs: dict[str, Path],
                                                              tmp_path: Path) -> None:
    """Items 7, 10: the one-run summary shows the robot's parameters and its log's path as
    wrapping text near the top; the several-run table has the inputs that vary right after
    the run's number (before: after seven columns, cut off), the log last."""
    rrd = tmp_path / "one.rrd"
    assert main(["replay", str(logs["fig11"]), "--rrd", str(rrd)]) == 0
    [text] = _summary(rrd)
    assert "| robot | m 25 kg" in text and "log **fig11.mcap** in" in text.split("|")[0]
    both = tmp_path / "two.rrd"
    assert main(["replay", str(logs["fig11"]), str(logs["near"]), "--rrd", str(both)]) == 0
    [text] = _summary(both)
    head = next(line for line in text.splitlines() if line.startswith("| run"))
    cells = [c.strip() for c in head.strip("|").split("|")]
    assert cells[:3] == ["run", "K_ps", "status"] and cells[-1] == "log"


def _summary(rrd: Path) -> list[str]:
    for chunk in rrc.RrdReader(rrd).stream():
        if chunk.entity_path == "/summary":
            batch = chunk.to_record_batch()
            if "TextDocument:text" in batch.schema.names:
                return [str(t) for t in batch.column("TextDocument:text").to_pylist()[0]]
    return []


@pytest.mark.slow
def test_the_optimal_run_is_in_every_panel_or_the_panel_says_why(logs: dict[str, Path],
                                                                 tmp_path: Path) -> None:
    """Item 3: ``wmr replay PI.mcap OPTIMAL.mcap``: the open-loop run has finite lines in the
    distance and heading-error panels (the stabiliser's errors along its path: its Δr is its
    distance to the goal), and the panels it has no line in (the commands, the phase) say
    in their titles that it is open loop (before: absent without a word)."""
    opt = tmp_path / "opt.mcap"
    assert main(["optimal", "--goal", "4", "2", "0", "--out", str(opt)]) == 0
    rrd = tmp_path / "both.rrd"
    assert main(["replay", str(logs["near"]), str(opt), "--rrd", str(rrd)]) == 0
    run = read_run(opt)
    values: dict[str, Any] = {}
    for chunk in rrc.RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        if chunk.entity_path.startswith("/runs/opt/") and "Scalars:scalars" in batch.schema.names:
            rows = batch.column("Scalars:scalars").to_pylist()
            values.setdefault(chunk.entity_path, []).extend(r[0] for r in rows)
    for panel in ("distance", "heading", "speed", "turn_rate", "wheels", "torques"):
        assert np.isfinite(values[f"/runs/opt/{panel}"]).any(), panel
    dr = np.array(values["/runs/opt/distance"])
    assert run.goal is not None
    np.testing.assert_allclose(dr, np.hypot(run.goal.x_m - run.signals["x_m"],
                                            run.goal.y_m - run.signals["y_m"]), atol=1e-6)
    titles = [v["name"] for v in _plots(rrd)]
    said = [t for t in titles if "#1 open loop" in t]
    assert len(said) == 3 and any(t.startswith("Phase") for t in said), titles


def test_raw_blueprint_plots_are_labelled_in_three_columns(logs: dict[str, Path],
                                                           tmp_path: Path) -> None:
    """Items 1, 4, 9, 10 for the raw log: the blueprint of ``--blueprint-for`` fixes each
    plot's y range to labelled values around the log's own values (before: e_θ and the
    torques showed only "0"), lays six cells in three columns with the phase in a tab
    behind the torques (before: two columns and an empty cell), and draws the robot dark
    (the path under it is blue)."""
    log = tmp_path / "fig11.mcap"
    log.write_bytes(logs["fig11"].read_bytes())
    assert main(["replay", "--blueprint-for", str(log)]) == 0
    _, ents = blueprint(log.with_suffix(".rbl"))
    plots = [v for v in views(ents) if v["class"] == "TimeSeries"]
    assert len(plots) == 7
    run = read_run(log)
    for v in plots:
        lo, hi = v["ScalarAxis:range"][0]
        assert _labelled(lo, hi) >= 2, (v["name"], lo, hi)
    [heading] = [v for v in plots if "e_θ" in v["name"]]
    lo, hi = heading["ScalarAxis:range"][0]
    assert lo <= float(run.signals["e_theta_rad"].min()) <= float(
        run.signals["e_theta_rad"].max()) <= hi
    [grid] = [c for c in ents.values() if c.get("ContainerBlueprint:container_kind") == [4]]
    assert grid["ContainerBlueprint:grid_columns"] == [3]
    assert len(grid["ContainerBlueprint:contents"]) == 6
    tabs = [c for c in ents.values() if c.get("ContainerBlueprint:container_kind") == [2]]
    assert len(tabs) == 1 and len(tabs[0]["ContainerBlueprint:contents"]) == 2
    [rgba] = [c["Points3D:colors"][0] for p, c in ents.items()
              if "/overrides/scene/robot/" in p and "Points3D:colors" in c]
    assert relative_luminance((rgba >> 24 & 255, rgba >> 16 & 255, rgba >> 8 & 255)) < 0.05

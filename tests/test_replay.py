"""``wmr replay``, the live view sinks, and Rerun's own MCAP loader on our logs."""

from __future__ import annotations

import io
import os
from collections.abc import Iterator
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import pyarrow as pa
import pytest
import rerun.chunk as rrc

from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import read_run
from wmr.adapters.rerun.live_view import TeeSink, live_view_sink
from wmr.adapters.rerun.replay import (
    PANELS,
    TIMELINE,
    default_rrd_path,
    find_logs,
    has_screen,
    replay,
)
from wmr.apps.run import run_to_log
from wmr.cli import main
from wmr.config.scenario import Overrides, load_scenario, with_overrides
from wmr.core.closedloop import run_closed_loop
from wmr.core.control.from_spec import SpecController
from wmr.core.runlog import MemoryLog
from wmr.core.runspec import RunSpec
from wmr.core.signals import SIGNALS
from wmr.infra.errors import LogError


@dataclass
class Entity:
    """Everything an .rrd holds for one entity: rows on the timeline, components, values."""

    rows: int = 0
    static_rows: int = 0
    components: set[str] = field(default_factory=set)
    columns: dict[str, list[pa.Array]] = field(default_factory=dict)
    times: list[pa.Array] = field(default_factory=list)

    def column(self, name: str) -> list[Any]:
        """All values of a component, in time order (as Python lists)."""
        values: list[Any] = []
        for arr in self.columns.get(name, []):
            values.extend(arr.to_pylist())
        return values


def read_rrd(path: Path) -> tuple[dict[str, Entity], int]:
    """Entities of the first recording of an .rrd file, and the number of blueprints."""
    reader = rrc.RrdReader(path)
    out: dict[str, Entity] = {}
    for chunk in reader.stream():
        ent = out.setdefault(chunk.entity_path, Entity())
        batch = chunk.to_record_batch()
        names = batch.schema.names
        timed = TIMELINE in names
        if timed:
            ent.rows += chunk.num_rows
            ent.times.append(batch.column(TIMELINE))
        else:
            ent.static_rows += chunk.num_rows
        for name in names:
            if ":" in name:
                ent.components.add(name)
                ent.columns.setdefault(name, []).append(batch.column(name))
    return out, len(reader.blueprints())


def run_cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = main(list(argv))
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def spec() -> RunSpec:
    return load_scenario("fig11").runs[0]


@pytest.fixture(autouse=True)
def no_screen(monkeypatch: pytest.MonkeyPatch) -> None:
    """Never spawn a viewer from the tests."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


def test_replay_rrd_holds_path_pose_goal_and_every_series(fig11_log: Path,
                                                           tmp_path: Path) -> None:
    run = read_run(fig11_log)
    n = run.n_steps
    assert n > 1000
    out = tmp_path / "fig11.rrd"
    rc, stdout, stderr = run_cli("replay", str(fig11_log), "--rrd", str(out))
    assert rc == 0, stderr
    assert stdout.strip() == str(out)
    assert "truncated" not in stderr

    ents, n_blueprints = read_rrd(out)
    assert n_blueprints == 1
    root = "/runs/fig11"
    # the path: one static strip through every logged position
    path = ents[f"{root}/world/path"]
    assert path.rows == 0 and path.static_rows == 1
    # a strip per control phase, each starting where the previous one ends
    strips = [np.array(s) for s in path.column("LineStrips2D:strips")[0]]
    assert len(strips) == 2  # the approach, then the alignment in place
    assert np.array_equal(strips[0][-1], strips[1][0])
    strip = np.concatenate([strips[0], *(s[1:] for s in strips[1:])])
    assert strip.shape == (n, 2)
    np.testing.assert_allclose(strip[:, 0], run.signals["x_m"], atol=1e-5)
    np.testing.assert_allclose(strip[:, 1], run.signals["y_m"], atol=1e-5)
    colors = path.column("LineStrips2D:colors")[0]
    assert len(colors) == 2 and colors[0] != colors[1]
    # the phase: the stabiliser's, approach until it is within half the stop radius
    phase = np.array(ents[f"{root}/phase"].column("Scalars:scalars")).ravel()
    assert phase.shape == (n,) and phase[0] == 0 and phase[-1] == 1
    first_align = int(np.argmax(phase == 1))
    assert run.signals["dr_m"][first_align] <= 0.5 * 0.05 < run.signals["dr_m"][first_align - 1]
    # the pose: a transform per step, on sim_time
    robot = ents[f"{root}/world/robot"]
    assert robot.rows == n
    assert {"Transform3D:translation", "Transform3D:quaternion", "Boxes2D:half_sizes",
            "Arrows2D:vectors"} <= robot.components
    trans = np.array([row[0] for row in robot.column("Transform3D:translation")])
    np.testing.assert_allclose(trans[:, 0], run.signals["x_m"], atol=1e-5)
    np.testing.assert_allclose(trans[:, 1], run.signals["y_m"], atol=1e-5)
    quat = np.array([row[0] for row in robot.column("Transform3D:quaternion")])
    # the robot's forward axis (body x) rotated by each quaternion must point along the logged
    # heading (cos theta, sin theta): the sine's sign tells a mirrored heading apart
    qx, qy, qz, qw = quat.T
    forward = np.column_stack([1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy + qw * qz)])
    theta = run.signals["theta_rad"]
    np.testing.assert_allclose(forward, np.column_stack([np.cos(theta), np.sin(theta)]),
                               atol=1e-5)
    assert np.max(np.abs(np.sin(theta))) > 0.1  # turns enough to tell a mirror apart
    times = np.concatenate([np.asarray(t.cast(pa.int64())) for t in robot.times])
    np.testing.assert_array_equal(times, run.t_ns)
    # the goal
    goal = ents[f"{root}/world/goal"]
    assert goal.static_rows == 1
    assert run.goal is not None
    np.testing.assert_allclose(goal.column("Arrows2D:origins")[0][0],
                               [run.goal.x_m, run.goal.y_m])
    # the points D and R, with their construction lines
    for point, (cx, cy) in {"D": ("D_x_m", "D_y_m"), "R": ("R_x_m", "R_y_m")}.items():
        ent = ents[f"{root}/world/{point}"]
        assert ent.rows == n
        pos = np.array([row[0] for row in ent.column("Points2D:positions")])
        np.testing.assert_allclose(pos[:, 0], run.signals[cx], atol=1e-4)
        np.testing.assert_allclose(pos[:, 1], run.signals[cy], atol=1e-4)
    assert ents[f"{root}/world/construction"].rows == n
    # every time-series panel, with each of its signals, on every step
    for panel in PANELS:
        ent = ents[f"{root}/{panel.entity}"]
        assert ent.rows == n, panel.entity
        values = np.array(ent.column("Scalars:scalars"))
        assert values.shape == (n, len(panel.series))
        for j, series in enumerate(panel.series):
            np.testing.assert_array_equal(values[:, j], run.signals[series.signal] * series.scale)
        names = ent.column("SeriesLines:names")[0]
        assert names == [s.label for s in panel.series]


def test_panels_cover_the_figures_signals() -> None:
    plotted = {s.signal for p in PANELS for s in p.series}
    assert {"e_s_m", "e_theta_rad", "omega_radps", "omega_r_radps", "omega_l_radps",
            "tau_r_nm", "tau_l_nm", "p_s_mps", "i_s_mps", "p_theta_radps",
            "i_theta_radps"} <= plotted
    assert plotted <= set(SIGNALS)


def test_truncated_log_replays_its_prefix_with_a_warning(fig11_log: Path,
                                                          tmp_path: Path) -> None:
    data = fig11_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    prefix = read_run(cut)
    full = read_run(fig11_log)
    assert prefix.truncated and 0 < prefix.n_steps < full.n_steps
    rc, stdout, stderr = run_cli("replay", str(cut))
    assert rc == 0
    assert "warning" in stderr and "truncated" in stderr
    out = Path(stdout.strip())
    assert out == tmp_path / "cut.rrd" and out.is_file()
    ents, _ = read_rrd(out)
    assert ents["/runs/cut/world/robot"].rows == prefix.n_steps
    assert ents["/runs/cut/distance"].rows == prefix.n_steps
    strip = ents["/runs/cut/world/path"].column("LineStrips2D:strips")[0][0]
    assert len(strip) == prefix.n_steps  # cut before the alignment: one strip


@pytest.mark.parametrize("content", [b"", os.urandom(4096), b"\x89MCAP0\r\n" + b"\0" * 64])
def test_corrupt_log_is_one_error_line(tmp_path: Path, content: bytes) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(content)
    rc, stdout, stderr = run_cli("replay", str(bad), "--rrd", str(tmp_path / "x.rrd"))
    assert rc == 1
    assert stdout == ""
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("wmr: error:") and "bad.mcap" in lines[0]
    with pytest.raises(LogError):
        replay([bad], rrd=tmp_path / "y.rrd")


def test_folder_of_runs_is_one_recording(fig11_log: Path, spec: RunSpec, fmu3_plant: FmuPlant,
                                         tmp_path: Path) -> None:
    batch = tmp_path / "batch"
    (batch / "a").mkdir(parents=True)
    (batch / "b").mkdir()
    (batch / "a" / "fig11.mcap").write_bytes(fig11_log.read_bytes())
    short = with_overrides(spec, Overrides(start=(10.0, 10.0, 90.0), name="short"))
    run_to_log(short, batch / "b" / "fig11.mcap", fmu3_plant)  # same file name, other folder
    run_to_log(short, batch / "b" / "other+run.mcap", fmu3_plant)
    logs = find_logs([batch])
    assert [lg.name for lg in logs] == ["a_fig11", "b_fig11", "other+run"]
    result = replay([batch])
    assert result.rrd == tmp_path / "batch.rrd" and not result.spawned
    ents, n_bp = read_rrd(tmp_path / "batch.rrd")
    assert n_bp == 1
    for lg in logs:
        root = f"/runs/{lg.name.replace('+', chr(92) + '+')}"
        assert ents[f"{root}/world/robot"].rows == read_run(lg.path).n_steps
        assert ents[f"{root}/world/path"].static_rows == 1
    for k, lg in enumerate(logs):  # each run's lines are named by its number, in its colour
        root = f"/runs/{lg.name.replace('+', chr(92) + '+')}"
        style = ents[f"{root}/distance"]
        assert style.column("SeriesLines:names")[0][0] == f"#{k}: Δr"
    # runs from one start share one label, on the first (b_fig11 and other+run: one start)
    starts = [ents[f"/runs/{lg.name.replace('+', chr(92) + '+')}/world/start"]
              .column("Points2D:labels")[0] for lg in logs]
    assert starts == [["#0"], ["#1 #2"], [""]]
    colors = [ents[f"/runs/{lg.name.replace('+', chr(92) + '+')}/distance"]
              .column("SeriesLines:colors")[0][0] for lg in logs]
    assert len(set(colors)) == len(logs)
    # one summary document (not one per run: the view shows a single document), a row per run
    # naming its log, its start, and the input that differs (the start only, here)
    docs = [path for path, e in ents.items() if "TextDocument:text" in e.components]
    assert docs == ["/summary"]
    [text] = ents["/summary"].column("TextDocument:text")[0]
    rows = [line for line in text.splitlines() if line.startswith("| #")]
    for k, lg in enumerate(logs):  # the number first, then the inputs that vary; the log last
        assert rows[k].startswith(f"| #{k} | ") and rows[k].endswith(f" | `{lg.name}` |")
    assert "(10.00, 10.00, 90°)" in text


def test_find_logs_errors(tmp_path: Path) -> None:
    with pytest.raises(LogError, match="no such file"):
        find_logs([tmp_path / "missing.mcap"])
    with pytest.raises(LogError, match=r"no \.mcap files"):
        find_logs([tmp_path])


def test_screen_and_default_paths(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    assert not has_screen()
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    assert has_screen()
    assert default_rrd_path([tmp_path / "x.mcap"]) == tmp_path / "x.rrd"
    assert default_rrd_path([tmp_path]) == tmp_path.parent / f"{tmp_path.name}.rrd"
    assert default_rrd_path([tmp_path / "a.mcap", tmp_path / "b.mcap"]) == (
        tmp_path / "replay.rrd")


def test_replay_refuses_a_non_rrd_output(fig11_log: Path, tmp_path: Path) -> None:
    rc, _, stderr = run_cli("replay", str(fig11_log), "--rrd", str(tmp_path / "x.txt"))
    assert rc == 1 and "must end in .rrd" in stderr


def test_live_view_sink_through_a_tee(spec: RunSpec, fmu3_plant: FmuPlant,
                                      tmp_path: Path) -> None:
    rrd = tmp_path / "live.rrd"
    recorder = MemoryLog()
    with live_view_sink(spec.name, spec.goal, rrd, start=spec.start,
                        stop_radius_m=spec.stop_radius_m) as live:
        result = run_closed_loop(spec, fmu3_plant, sink=TeeSink(recorder, live),
                                 controller=SpecController())
    assert result.status == "converged"
    n = result.steps
    assert recorder.rows == n
    assert live.rows == n
    ents, n_bp = read_rrd(rrd)
    assert n_bp == 1 + live.reframed  # the fig11 path leaves the start-goal frame once
    root = f"/runs/{spec.name}"
    block = recorder.block
    x_min, x_max, y_min, y_max = _world_bounds(rrd)[-1]
    xy = block[:, [SIGNALS.index("x_m"), SIGNALS.index("y_m")]]
    assert x_min <= xy[:, 0].min() and xy[:, 0].max() <= x_max
    assert y_min <= xy[:, 1].min() and xy[:, 1].max() <= y_max
    for panel in PANELS:
        values = np.array(ents[f"{root}/{panel.entity}"].column("Scalars:scalars"))
        assert values.shape == (n, len(panel.series))
        for j, series in enumerate(panel.series):
            np.testing.assert_array_equal(values[:, j],
                                          block[:, SIGNALS.index(series.signal)] * series.scale)
    assert ents[f"{root}/world/robot"].rows == n
    # the path grows every 400 rows (4 blocks); its last version ends where the robot stopped
    path = ents[f"{root}/world/path"]
    assert path.rows == -(-n // 400)
    last = np.array(path.column("LineStrips2D:strips")[-1][-1])  # a strip per phase
    np.testing.assert_allclose(last[-1], [result.final_pose.x_m, result.final_pose.y_m],
                               atol=1e-5)
    assert ents[f"{root}/world/goal"].static_rows == 1


def _world_bounds(rrd: Path) -> list[tuple[float, float, float, float]]:
    """``(x_min, x_max, y_min, y_max)`` of the world view of each blueprint in ``rrd``, in
    the order sent (the view's y axis points down: the range is mirrored back)."""
    reader = rrc.RrdReader(rrd)
    out = []
    for store in reader.blueprints():
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            if "VisualBounds2D:range" in batch.schema.names:
                [r] = batch.column("VisualBounds2D:range").to_pylist()[0]
                out.append((*r["x_range"], -r["y_range"][1], -r["y_range"][0]))
    return out


def test_live_view_has_the_phase_and_a_fixed_world_frame(tmp_path: Path) -> None:
    """The live view, as the replay: the phase (the hysteresis carried across sends: the
    distance sits between the two radii at a send boundary) as a signal and as the colours
    of the path and the heading; the world framed on the start and the goal from the first
    blueprint, re-framed only when the path leaves it, and then holding all of it."""
    n, eps = 1000, 0.5
    t = np.arange(n, dtype=np.int64) * 10_000_000
    rows = np.zeros((n, len(SIGNALS)))
    s = np.linspace(0.0, 1.0, n)
    rows[:, SIGNALS.index("x_m")], rows[:, SIGNALS.index("y_m")] = 4 * s, 6 * np.sin(np.pi * s)
    dr = np.full(n, 3.0)
    dr[350:380], dr[380:700], dr[800:] = 0.2, 0.5, 0.1  # align, hold it past row 400, ...
    rows[:, SIGNALS.index("dr_m")] = dr
    rrd = tmp_path / "live.rrd"
    with live_view_sink("live", (4.0, 0.0, 0.0), rrd, spawn=False, start=(0.0, 0.0, 0.0),
                        stop_radius_m=eps) as live:
        for i in range(0, n, 100):
            live.write_block(t[i:i + 100], rows[i:i + 100])
    want = np.zeros(n)
    want[350:700], want[800:] = 1, 1  # approach, align, approach again (dr > 2 eps), align
    ents, _ = read_rrd(rrd)
    np.testing.assert_array_equal(np.ravel(ents["/runs/live/phase"].column("Scalars:scalars")),
                                  want)
    heading = np.array(ents["/runs/live/world/robot"].column("Arrows2D:colors"))
    np.testing.assert_array_equal(heading != heading[0], want[:, None] != 0)
    path = ents["/runs/live/world/path"]
    strips = path.column("LineStrips2D:strips")[-1]
    assert len(strips) == 4 and len(set(path.column("LineStrips2D:colors")[-1])) == 2
    # the frame only grows, and the recording need not keep the blueprints' order
    first, *later = sorted(_world_bounds(rrd), key=lambda b: (b[1] - b[0]) * (b[3] - b[2]))
    inside = [(0.0, 0.0), (4.0, 0.0), (5.0, 0.0)]  # start, goal, the goal's arrow tip
    assert all(first[0] <= x <= first[1] and first[2] <= y <= first[3] for x, y in inside)
    assert first[3] < 6.0 and len(later) == live.reframed == 1  # the path left it once
    xy = rows[:, [SIGNALS.index("x_m"), SIGNALS.index("y_m")]]
    last = later[-1]
    assert (xy[:, 0] >= last[0]).all() and (xy[:, 0] <= last[1]).all()
    assert (xy[:, 1] >= last[2]).all() and (xy[:, 1] <= last[3]).all()
    assert ents["/grid/lines"].static_rows >= 1


def test_live_view_default_rrd_without_screen(spec: RunSpec, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    sink = live_view_sink("a run/with spaces", (1.0, 2.0, 0.5), None)
    t = np.arange(3, dtype=np.int64) * 10_000_000
    sink.write_block(t, np.zeros((3, len(SIGNALS))))
    sink.close()
    out = tmp_path / "runs" / "a%20run%2Fwith%20spaces.rrd"  # one-to-one with the name
    assert out.is_file()
    ents, _ = read_rrd(out)
    assert ents["/runs/a\\ run\\/with\\ spaces/distance"].rows == 3


def test_rerun_reads_our_mcap_log_natively(fig11_log: Path) -> None:
    """Rerun's own MCAP loader (no lens, no help from us) yields the pose and the transform."""
    run = read_run(fig11_log)
    n = run.n_steps
    reader = rrc.McapReader(fig11_log)
    assert "foxglove" in rrc.McapReader.available_decoders()
    poses: list[list[float]] = []
    frames: set[str] = set()
    parents: set[str] = set()
    children: set[str] = set()
    tf_rows = 0
    for chunk in reader.stream():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if chunk.entity_path == "/robot/pose" and "InstancePoses3D:translations" in names:
            poses.extend(row[0] for row in batch.column("InstancePoses3D:translations")
                         .to_pylist())
            frames.update(f[0] for f in batch.column("CoordinateFrame:frame").to_pylist())
        if chunk.entity_path == "/tf" and "Transform3D:translation" in names:
            tf_rows += chunk.num_rows
            parents.update(f[0] for f in batch.column("Transform3D:parent_frame").to_pylist())
            children.update(f[0] for f in batch.column("Transform3D:child_frame").to_pylist())
    assert len(poses) == n and tf_rows == n
    xy = np.array(poses)[:, :2]
    np.testing.assert_allclose(xy[:, 0], run.signals["x_m"], atol=1e-5)
    np.testing.assert_allclose(xy[:, 1], run.signals["y_m"], atol=1e-5)
    assert frames == {"world"}
    assert parents == {"world"} and children == {"base_link"}


def test_rerun_recovers_a_cut_mcap_log(fig11_log: Path, tmp_path: Path) -> None:
    data = fig11_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    rows = 0
    for chunk in rrc.McapReader(cut, recover=True).stream():
        if chunk.entity_path == "/tf" and "Transform3D:translation" in (
                chunk.to_record_batch().schema.names):
            rows += chunk.num_rows
    assert 0 < rows < read_run(fig11_log).n_steps


# -- issue 28 item 9: --rrd and --blueprint on a full disk --------------------------------------


@pytest.fixture
def full_disk(tmp_path: Path) -> Iterator[Path]:
    """A 2 MiB tmpfs (root only; skipped where mounting is not allowed)."""
    import subprocess

    mnt = tmp_path / "disk"
    mnt.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)],
                          capture_output=True, check=False)
    if proc.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def _fill(folder: Path, leave: int) -> None:
    """Fill the device of ``folder`` but for about ``leave`` bytes."""
    free = os.statvfs(folder).f_bavail * os.statvfs(folder).f_frsize
    (folder / "filler").write_bytes(bytes(max(0, free - leave)))


#: Free bytes that a recording of fig11 (1.22 MiB) fills in the middle of its write, above the
#: 1 MiB under which bf01f8f refused before writing.
_MID_WRITE: Final = (1 << 20) + (128 << 10)


@pytest.mark.parametrize(("option", "leave"), [("--rrd", 4096), ("--blueprint", 4096),
                                               ("--rrd", _MID_WRITE),
                                               ("--blueprint", 128 << 10)])
def test_a_full_disk_keeps_the_previous_recording_and_says_so_in_one_line(
        fig11_log: Path, full_disk: Path, option: str, leave: int) -> None:
    """Before: `internal error: RuntimeError: File-writer thread shut down prematurely`, the
    previous .rrd overwritten by a truncated one (the blueprint alike), or a hang in Rerun's
    save when one of its writes fails: a disk full before the write (4 KiB left), or during
    it (1.125 MiB left for 1.22 MiB of recording; 128 KiB for a 240 KB blueprint)."""
    out = full_disk / ("x.rrd" if option == "--rrd" else "x.rbl")
    previous = b"the previous good file"
    out.write_bytes(previous)
    _fill(full_disk, leave)
    import subprocess
    import sys

    # in a process of its own: the old code could hang in Rerun's flush in-process
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run([sys.executable, "-m", "wmr.cli", "replay", str(fig11_log), option,
                           str(out)], env=env, capture_output=True, text=True, timeout=60,
                          check=False)
    # Rerun's own logger adds its lines (ERROR re_log_encoding::...): ours is one line
    lines = [line for line in proc.stderr.splitlines() if line.startswith("wmr:")]
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"wmr: error: no space left on {full_disk} while writing {out}")
    assert out.read_bytes() == previous
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler", out.name]  # no temp left


# -- issue 28 item 12: a folder's links and bad files --------------------------------------------


def test_a_folder_replays_its_good_logs_skipping_bad_ones_and_links_outside(
        fig11_log: Path, tmp_path: Path) -> None:
    """Before: ``wmr replay DIR`` followed a link to a file outside DIR, and one bad file
    stopped the whole replay.  Now each is one line on stderr, the others are replayed, and
    the exit status (4) says some were skipped."""
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.mcap").write_bytes(fig11_log.read_bytes())
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "good.mcap").write_bytes(fig11_log.read_bytes())
    (runs / "bad.mcap").write_bytes(b"not a log at all")
    (runs / "link.mcap").symlink_to(outside / "secret.mcap")
    (runs / "inside.mcap").symlink_to(runs / "good.mcap")  # a link within the folder: kept
    code, _, err = run_cli("replay", str(runs), "--rrd", str(tmp_path / "r.rrd"))
    lines = [line for line in err.splitlines() if line.startswith("wmr: ")]
    assert code == 4, err
    assert any(line.startswith(f"wmr: {runs / 'link.mcap'}: skipped: a link to ")
               and "outside" in line for line in lines), lines
    assert any(line.startswith(f"wmr: skipped: {runs / 'bad.mcap'}: ") for line in lines), lines
    assert "wrote 2 runs" in err, err
    ents, _ = read_rrd(tmp_path / "r.rrd")
    assert {e.split("/")[2] for e in ents if e.startswith("/runs/")} == {"good", "inside"}
    # every log bad: one line, exit 1, as for a single bad file
    (runs / "good.mcap").write_bytes(b"neither")
    code, _, err = run_cli("replay", str(runs), "--rrd", str(tmp_path / "s.rrd"))
    assert code == 1 and len(err.strip().splitlines()) == 1, err


def test_replay_logs_names_its_arguments_in_the_callers_words(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``apps.replay.replay_logs``, the function both ``wmr replay`` and ``wmr.replay`` call:
    no log, and ``worst`` without one batch folder, are errors naming the argument as the
    caller wrote it (the keyword for the API, the option for the command line, which
    translates the keyword)."""
    from wmr.apps.replay import ReplayRequest, replay_logs
    from wmr.infra.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        replay_logs(ReplayRequest())
    assert err.value.field == "logs" and "no log given" in str(err.value)
    assert main(["replay"]) == 1
    assert capsys.readouterr().err.startswith("wmr: error: FILE.mcap|DIR: no log given")
    (tmp_path / "a.mcap").write_bytes(b"")
    with pytest.raises(ConfigError) as err:
        replay_logs(ReplayRequest([tmp_path / "a.mcap"], worst=3))
    assert err.value.field == "worst" and "batch folder" in str(err.value)

"""Screenshots of the real Rerun viewer for docs/replay.md: our replay and the raw MCAP log.

Runs the logs (or takes them from ``--logs``), makes the recordings with the ``wmr`` of the
current ``PYTHONPATH``, opens each in the ``rerun`` binary of the rerun-sdk wheel on a
software-rendered X server (Xvfb, Mesa's Vulkan driver), waits, grabs the screen with
ImageMagick's ``import`` and writes a small PNG (a 256-colour palette: under 200 KB).

Needs (Debian): ``xvfb mesa-vulkan-drivers libgl1-mesa-dri libvulkan1 imagemagick``.

Usage::

    PYTHONPATH=pipelines python tools/screenshots.py --out docs/img
    PYTHONPATH=pipelines python tools/screenshots.py --out /tmp/shots --only single raw

Shots (``NAME.png``):

``single``   ``wmr replay fig11.mcap``: the Fig. 11 run;
``sensors``  ``wmr replay`` of the Fig. 11 run with ``--sensors gps``;
``overlay``  ``wmr replay`` of a 20-run batch folder (random starts, robot parameters);
``raw``      the raw log through Rerun's own loader: ``rerun mcap convert --timeline-type
             duration --application-id wmr-run`` and the blueprint of ``wmr replay --blueprint``;
``direct``   the raw log opened as it is with the blueprint beside it, ``rerun fig11.mcap
             fig11.rbl`` (``wmr replay --blueprint-for``), in a viewer with the two settings
             of docs/replay.md (:data:`DIRECT_SETTINGS`: files not loaded via the Viewer
             catalog, times as seconds since the Unix epoch); a ``wmr`` without that option:
             the log alone in a viewer as installed (Rerun's own layout);
``bare``     ``rerun fig11.mcap``, nothing else, in a viewer of Rerun's default settings: its
             own layout and the log's note (``/wmr/readme``) saying what to run;
``live``     the ``.rrd`` of ``wmr run fig11 --view`` without a screen (the live view);
``recovered`` the log of a Fig. 11 run killed after 15 s of simulation, recovered by ``wmr
             log recover`` and opened as it is (``rerun X.recovered.mcap``, Rerun's own
             layout);
``optimal``  ``wmr replay fig11.mcap optimal-time.mcap``: the PI's Fig. 11 run against the
             minimum-time manoeuvre of ``wmr optimal fig11`` (an open-loop log);
``robot``    ``wmr replay fig11.mcap robot.mcap``: the Fig. 11 run against a real robot's
             log of the same manoeuvre (:func:`robot_log`: a heavier robot with motor
             friction, simulated, logged as a robot's localisation would: poses only, 20 Hz,
             5 mm of noise, wall-clock times, standing 2 s before it moves), aligned at the
             start of motion, the distance between the paths plotted (docs/replay.md);
``worst``    ``wmr replay DIR --worst 5 --by final_position_error_m`` of the Monte Carlo
             ``scenarios/mc_failures.toml`` (800 runs, about a tenth time out; ``--log
             failed``): the five runs that ended furthest from the goal
             (docs/batch_walkthrough.md).

Xvfb needs ``-extension COMPOSITE`` (else every grab is black); each viewer gets a private
``--port``, ``XDG_RUNTIME_DIR`` and ``XDG_DATA_HOME`` (its settings: never the user's), and is
stopped by its own process id.  The shots that open an MCAP file or play a live recording wait
longer (:data:`WAIT_FACTOR`): the software-rendered viewer imports and plays slowly.  A grab that is
nearly one colour (the viewer not drawn yet) is retried after another wait.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHOTS = ("single", "sensors", "overlay", "raw", "direct", "live", "recovered", "worst",
         "optimal", "robot", "bare")
#: The viewer settings of the ``direct`` shot (a partial ``app.ron`` of the native viewer's
#: persisted state): a blueprint given next to a file applies only when the file is not
#: loaded via the Viewer catalog (Rerun 0.41's release notes), and the log time (ns from the
#: start) reads as seconds only in the "seconds since Unix epoch" time format.
DIRECT_SETTINGS = (
    '{"app": "(app_options:(use_viewer_catalog:false,timestamp_format:'
    '(format_kind:SecondsSinceUnixEpoch,date_visibility:HideDateToday,short:false)))"}\n')
#: Longer waits before the grab (times ``--wait``).
WAIT_FACTOR = {"direct": 2.0, "recovered": 2.0, "live": 2.5, "bare": 2.0}
#: The killed run of the ``recovered`` shot dies after this many rows (15 s of the Fig. 11 run).
KILL_AFTER_ROWS = 1500
#: Runs the Fig. 11 run into ``argv[1]`` and dies like a SIGKILL after ``argv[2]`` rows.
_KILLED_RUN = """
import os, sys
from wmr.adapters.fmi.robot import FmuPlant
from wmr.apps.run import default_fmu, run_to_log
from wmr.config.scenario import load_scenario

class Kill:
    rows = 0
    def write_block(self, t_ns, block):
        self.rows += len(t_ns)
        if self.rows >= int(sys.argv[2]):
            os._exit(9)

with FmuPlant(default_fmu()) as plant:
    run_to_log(load_scenario("fig11").runs[0], sys.argv[1], plant, also=Kill())
"""
#: Screen size of the X server and of the viewer window, pixels.
WIDTH, HEIGHT = 1600, 1000
#: The 20-run overlay: the Monte Carlo spec of Fig. 10 cut to 20 runs.
OVERLAY_RUNS = 20
#: The runs of the ``worst`` shot: the worst of the ``mc_failures`` batch.
WORST_RUNS = 5
#: Size limit of a PNG in docs/img.
MAX_PNG_BYTES = 200_000


def _run(cmd: Sequence[str | Path], *, quiet: bool = False, check: bool = True,
         env: dict[str, str] | None = None) -> int:
    print("+", " ".join(str(c) for c in cmd), file=sys.stderr, flush=True)
    return subprocess.run([str(c) for c in cmd], check=check, env=env,
                          stdout=subprocess.DEVNULL if quiet else None).returncode


def _no_screen() -> dict[str, str]:
    """The environment without a display: ``wmr run --view`` writes its ``.rrd``."""
    return {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}


def _has_blueprint_for() -> bool:
    """Whether the ``wmr`` of this ``PYTHONPATH`` has ``replay --blueprint-for``."""
    res = subprocess.run([*map(str, _wmr()), "replay", "--help"], capture_output=True,
                         text=True, check=True)
    return "--blueprint-for" in res.stdout


def _wmr() -> list[str | Path]:
    return [sys.executable, "-m", "wmr.cli"]


def make_logs(folder: Path) -> dict[str, Path]:
    """The logs of the four shots, run now into ``folder`` (kept when already there)."""
    folder.mkdir(parents=True, exist_ok=True)
    logs = {"single": folder / "fig11.mcap", "sensors": folder / "fig11_gps.mcap",
            "overlay": folder / "mc20" / "runs"}
    if not logs["single"].exists():
        _run([*_wmr(), "run", "fig11", "--out", logs["single"]], quiet=True)
    if not logs["sensors"].exists():
        _run([*_wmr(), "run", "fig11", "--sensors", "gps", "--out", logs["sensors"]], quiet=True)
    if not logs["overlay"].exists():
        spec = (ROOT / "scenarios" / "mc_fig10.toml").read_text()
        spec = spec.replace('name = "mc_fig10"', 'name = "mc20"').replace(
            "n = 1000", f"n = {OVERLAY_RUNS}")
        (folder / "mc20.toml").write_text(spec)
        _run([*_wmr(), "batch", folder / "mc20.toml", "--out", folder / "mc20", "--no-progress",
              "--workers", "1"], quiet=True)
    logs["raw"] = logs["direct"] = logs["single"]
    logs["optimal"] = folder / "optimal-time.mcap"
    return logs


#: The "real robot" of the ``robot`` shot: the paper's robot 15 kg heavier, with motor friction.
ROBOT_PARAMS = ("m=40", "b_f=0.5")


def robot_log(sim: Path, out: Path, *, still_s: float = 2.0, hz: float = 20.0,
              noise_m: float = 0.005, t0_ns: int = 1_764_000_000_000_000_000) -> Path:
    """The run of ``sim`` as a real robot logs it: ``foxglove.PoseInFrame`` on
    ``/robot/pose`` only (``mcap-protobuf-support``'s own Writer), at ``hz``, with uniform
    position noise of ``noise_m``, log times on the wall clock from ``t0_ns``, and ``still_s``
    of standing before it moves."""
    import math

    import numpy as np
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    from mcap_protobuf.writer import Writer

    from wmr.adapters.mcap import read_run

    run = read_run(sim)
    t = run.t_s
    tau = np.arange(0.0, still_s + t[-1] + 1.0, 1.0 / hz)
    at = np.clip(tau - still_s, 0.0, t[-1])
    rng = np.random.default_rng(12)
    xy = np.column_stack([np.interp(at, t, run.signals[k]) for k in ("x_m", "y_m")])
    xy += rng.uniform(-noise_m, noise_m, xy.shape)
    yaw = np.interp(at, t, run.signals["theta_rad"])
    with out.open("wb") as f:
        w = Writer(f)
        for ti, (x, y), th in zip(tau, xy, yaw, strict=True):
            ns = t0_ns + round(ti * 1e9)
            m = PoseInFrame(frame_id="odom")
            m.timestamp.FromNanoseconds(ns)
            m.pose.position.x, m.pose.position.y = x, y
            m.pose.orientation.z, m.pose.orientation.w = math.sin(th / 2), math.cos(th / 2)
            w.write_message("/robot/pose", m, log_time=ns, publish_time=ns)
        w.finish()
    return out


def make_recordings(logs: dict[str, Path], folder: Path,
                    only: Sequence[str]) -> dict[str, list[Path]]:
    """What the viewer opens for each shot: an ``.rrd`` (and, for ``raw``, the ``.rbl``)."""
    out: dict[str, list[Path]] = {}
    for shot in only:
        rrd = folder / f"{shot}.rrd"
        if shot == "direct":
            out[shot] = [logs["direct"]]
            if _has_blueprint_for():  # X.rbl beside X.mcap, named for Rerun's import of it
                _run([*_wmr(), "replay", "--blueprint-for", logs["direct"]], quiet=True)
                out[shot].append(logs["direct"].with_suffix(".rbl"))
        elif shot == "live":
            log = folder / "live" / "fig11.mcap"
            _run([*_wmr(), "run", "fig11", "--view", "--out", log], quiet=True,
                 env=_no_screen())
            out[shot] = [log.with_suffix(".rrd")]
        elif shot == "recovered":
            killed = folder / "killed" / "fig11.mcap"
            killed.parent.mkdir(parents=True, exist_ok=True)
            code = _run([sys.executable, "-c", _KILLED_RUN, killed, str(KILL_AFTER_ROWS)],
                        check=False)
            if code != 9:
                raise SystemExit(f"the killed run ended with {code}, not 9")
            _run([*_wmr(), "log", "recover", f"{killed}.partial"], quiet=True)
            out[shot] = [killed.with_name("fig11.recovered.mcap")]
        elif shot == "worst":
            batch = folder / "mc_failures"
            _run([*_wmr(), "batch", ROOT / "scenarios" / "mc_failures.toml", "--out", batch,
                  "--log", "failed", "--no-progress", "--workers", "2"], quiet=True)
            _run([*_wmr(), "replay", batch, "--worst", str(WORST_RUNS), "--by",
                  "final_position_error_m", "--no-viewer",
                  "--rrd", rrd], quiet=True)
            out[shot] = [rrd]
        elif shot == "optimal":
            if not logs["optimal"].exists():
                _run([*_wmr(), "optimal", "fig11", "--out", logs["optimal"]], quiet=True)
            _run([*_wmr(), "replay", logs["single"], logs["optimal"], "--rrd", rrd],
                 quiet=True)
        elif shot == "bare":
            out[shot] = [logs["single"]]
        elif shot == "robot":
            heavy = folder / "robot_sim.mcap"
            _run([*_wmr(), "run", "fig11", *(a for p in ROBOT_PARAMS for a in ("--param", p)),
                  "--out", heavy], quiet=True)
            robot = robot_log(heavy, folder / "robot.mcap")
            _run([*_wmr(), "replay", logs["single"], robot, "--rrd", rrd], quiet=True)
            out[shot] = [rrd]
        elif shot == "raw":
            rbl = folder / "wmr.rbl"
            _run([*_wmr(), "replay", "--blueprint", rbl, logs["raw"]], quiet=True)
            rerun = shutil.which("rerun") or "rerun"
            _run([rerun, "mcap", "convert", logs["raw"], "--timeline-type", "duration",
                  "--application-id", "wmr-run", "-o", rrd], quiet=True)
            out[shot] = [rrd, rbl]
        else:
            _run([*_wmr(), "replay", logs[shot], "--rrd", rrd], quiet=True)
            out[shot] = [rrd]
    return out


def viewer_binary() -> str:
    """The ``rerun`` executable shipped in the rerun-sdk wheel (package ``rerun_cli``)."""
    import rerun_cli

    return str(Path(rerun_cli.__file__).parent / "rerun")


class Screen:
    """An Xvfb server on ``display`` for the lifetime of the ``with`` block."""

    def __init__(self, display: int) -> None:
        self.display = display
        self.proc: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> Screen:
        self.proc = subprocess.Popen(
            ["Xvfb", f":{self.display}", "-screen", "0", f"{WIDTH}x{HEIGHT}x24",
             "-extension", "COMPOSITE", "-nolisten", "tcp"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(2.0)
        if self.proc.poll() is not None:
            raise SystemExit(f"Xvfb :{self.display} did not start (display in use? --display)")
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout=10)


def _colours(png: Path) -> int:
    """Number of distinct colours of an image (a blank grab has one or two)."""
    res = subprocess.run(["identify", "-format", "%k", str(png)], capture_output=True,
                         text=True, check=True)
    return int(res.stdout.strip() or 0)


def grab(files: Sequence[Path], png: Path, *, display: int, port: int, wait_s: float,
         runtime: Path, settings: str | None = None) -> None:
    """Open ``files`` in a viewer, wait, grab the screen into ``png``, stop the viewer.

    ``settings``: the viewer's persisted state to start from (``app.ron``); None: the
    viewer's defaults.
    """
    data = Path(tempfile.mkdtemp(prefix="data-", dir=runtime))
    env = {**os.environ, "DISPLAY": f":{display}", "WGPU_BACKEND": "vulkan",
           "XDG_RUNTIME_DIR": str(runtime), "XDG_DATA_HOME": str(data)}
    persist = []
    if settings is not None:
        (data / "rerun").mkdir()
        (data / "rerun" / "app.ron").write_text(settings)
        persist = ["--persist-state"]
    # the binary itself, in a session of its own: the `rerun` script of the wheel is a Python
    # wrapper whose child would outlive a signal sent to the wrapper
    viewer = subprocess.Popen(
        [viewer_binary(), "--port", str(port), "--window-size", f"{WIDTH}x{HEIGHT}",
         "--hide-welcome-screen", *persist, *map(str, files)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        raw = png.with_suffix(".full.png")
        for attempt in range(4):
            time.sleep(wait_s if attempt == 0 else wait_s / 2)
            _run(["import", "-display", f":{display}", "-window", "root", str(raw)])
            if _colours(raw) > 50:
                break
            print(f"{png.name}: blank grab, waiting longer", file=sys.stderr)
        # a palette keeps a UI screenshot sharp and small (docs/img: under 200 KB each)
        for colors in (256, 128, 64):
            _run(["convert", str(raw), "-colors", str(colors), "-strip", f"PNG8:{png}"])
            if png.stat().st_size < MAX_PNG_BYTES:
                break
        raw.unlink()
    finally:
        os.killpg(viewer.pid, signal.SIGTERM)  # the viewer's own session, by its id
        try:
            viewer.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(viewer.pid, signal.SIGKILL)
            viewer.wait()
    print(f"{png}: {png.stat().st_size // 1024} KB", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img", help="PNG folder")
    ap.add_argument("--logs", type=Path, help="folder of the logs (default: a scratch folder)")
    ap.add_argument("--only", nargs="+", choices=SHOTS, default=list(SHOTS))
    ap.add_argument("--prefix", default="", help="prefix of the PNG names (e.g. before_)")
    ap.add_argument("--display", type=int, default=98)
    ap.add_argument("--port", type=int, default=19876, help="the viewer's private port")
    ap.add_argument("--wait", type=float, default=25.0, help="seconds before a grab")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="wmr-shots-") as tmp:
        work = Path(tmp)
        runtime = work / "xdg"
        runtime.mkdir(mode=0o700)
        logs = make_logs(args.logs or work / "logs")
        recordings = make_recordings(logs, work, args.only)
        with Screen(args.display):
            for k, shot in enumerate(args.only):  # a port per viewer: never an old one
                files = recordings[shot]
                settings = (DIRECT_SETTINGS if shot == "direct"
                            and any(f.suffix == ".rbl" for f in files) else None)
                grab(files, args.out / f"{args.prefix}{shot}.png", display=args.display,
                     port=args.port + k, wait_s=args.wait * WAIT_FACTOR.get(shot, 1.0),
                     runtime=runtime, settings=settings)
    return 0


if __name__ == "__main__":
    sys.exit(main())

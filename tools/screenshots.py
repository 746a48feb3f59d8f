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
``direct``   the raw log opened as it is, ``rerun fig11.mcap`` (Rerun's own layout).

Xvfb needs ``-extension COMPOSITE`` (else every grab is black); each viewer gets a private
``--port`` and ``XDG_RUNTIME_DIR``, and is stopped by its own process id.  A grab that is
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
SHOTS = ("single", "sensors", "overlay", "raw", "direct")
#: Screen size of the X server and of the viewer window, pixels.
WIDTH, HEIGHT = 1600, 1000
#: The 20-run overlay: the Monte Carlo spec of Fig. 10 cut to 20 runs.
OVERLAY_RUNS = 20
#: Size limit of a PNG in docs/img.
MAX_PNG_BYTES = 200_000


def _run(cmd: Sequence[str | Path], *, quiet: bool = False) -> None:
    print("+", " ".join(str(c) for c in cmd), file=sys.stderr, flush=True)
    subprocess.run([str(c) for c in cmd], check=True,
                   stdout=subprocess.DEVNULL if quiet else None)


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
    return logs


def make_recordings(logs: dict[str, Path], folder: Path,
                    only: Sequence[str]) -> dict[str, list[Path]]:
    """What the viewer opens for each shot: an ``.rrd`` (and, for ``raw``, the ``.rbl``)."""
    out: dict[str, list[Path]] = {}
    for shot in only:
        rrd = folder / f"{shot}.rrd"
        if shot == "direct":
            out[shot] = [logs["direct"]]
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
         runtime: Path) -> None:
    """Open ``files`` in a viewer, wait, grab the screen into ``png``, stop the viewer."""
    env = {**os.environ, "DISPLAY": f":{display}", "WGPU_BACKEND": "vulkan",
           "XDG_RUNTIME_DIR": str(runtime)}
    # the binary itself, in a session of its own: the `rerun` script of the wheel is a Python
    # wrapper whose child would outlive a signal sent to the wrapper
    viewer = subprocess.Popen(
        [viewer_binary(), "--port", str(port), "--window-size", f"{WIDTH}x{HEIGHT}",
         "--hide-welcome-screen", *map(str, files)],
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
                grab(recordings[shot], args.out / f"{args.prefix}{shot}.png",
                     display=args.display, port=args.port + k, wait_s=args.wait,
                     runtime=runtime)
    return 0


if __name__ == "__main__":
    sys.exit(main())

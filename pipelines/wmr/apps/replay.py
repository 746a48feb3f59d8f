"""What ``wmr replay`` and :func:`wmr.replay` both do: check the inputs, then replay run logs in
Rerun (:func:`wmr.adapters.rerun.replay.replay`) or write blueprints for Rerun's own MCAP
loader (:func:`wmr.adapters.rerun.blueprint.write_blueprint`, one file;
:func:`~wmr.adapters.rerun.blueprint.write_log_blueprint`, ``X.rbl`` beside each ``X.mcap``)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from wmr.infra.errors import ConfigError

if TYPE_CHECKING:
    from wmr.adapters.rerun.replay import ReplayResult

#: The API's keywords -> the options of ``wmr replay`` that give them.
_FLAGS = {"logs": "FILE.mcap|DIR", "rrd": "--rrd", "blueprint": "--blueprint",
          "blueprint_for": "--blueprint-for"}


def replay_logs(logs: Sequence[str | os.PathLike[str]] = (), *,
                rrd: str | os.PathLike[str] | None = None,
                blueprint: str | os.PathLike[str] | None = None, blueprint_for: bool = False,
                viewer: bool | None = None,
                command_line: bool = False) -> ReplayResult | Path | list[Path]:
    """Replay ``logs`` (files and folders of them) in one Rerun recording, or, with
    ``blueprint``, write that blueprint file (looking straight down on ``logs``, if given)
    and replay nothing.

    Parameters
    ----------
    logs
        ``.mcap`` run logs and folders searched recursively for them.
    rrd
        Write the recording to this ``.rrd`` file.
    blueprint
        Write a Rerun blueprint (``.rbl``) for a log opened with Rerun's own MCAP loader
        (``docs/replay.md``), and stop.
    blueprint_for
        Write ``X.rbl`` beside each log ``X.mcap`` (looking down on its own run), so that
        ``rerun X.mcap X.rbl`` applies it, and stop.
    viewer
        Open a viewer: None when there is a screen and no ``rrd``, False never (then the
        recording goes to ``rrd`` or next to the input).
    command_line
        Name the options in errors as ``wmr replay`` does (``--rrd``), else the keywords.

    Returns
    -------
    ReplayResult, Path or list of Path
        What the replay did, the blueprint written, or those written beside the logs.

    Raises
    ------
    ConfigError
        No log given, or an output that cannot be written.
    LogError
        A log that cannot be read.
    """
    from wmr.infra.outputs import check_output

    def option(keyword: str) -> str:
        return _FLAGS[keyword] if command_line else keyword

    if blueprint_for:
        from wmr.adapters.rerun.blueprint import log_blueprint_path, write_log_blueprint
        from wmr.adapters.rerun.replay import find_logs, framing

        if not logs:
            raise ConfigError(option("blueprint_for"), "no log given",
                              "give run logs or folders of them: wmr replay --blueprint-for "
                              "X.mcap" if command_line else "give run logs or folders of them")
        found = find_logs(logs)
        for log in found:  # every output checked before the first is written
            check_output(log_blueprint_path(log.path), option("blueprint_for"), suffix=".rbl")
        written = []
        for log in found:
            own_frame, own_sensing = framing([log.path])  # each looks down on its own run
            written.append(write_log_blueprint(log.path, own_frame, sensing=own_sensing))
        return written
    if blueprint is not None:
        from wmr.adapters.rerun.blueprint import write_blueprint

        frame, sensing = None, False
        if logs:  # look straight down on these runs (and plot their covariance)
            from wmr.adapters.rerun.replay import framing

            frame, sensing = framing(logs)
        out = check_output(blueprint, option("blueprint"), suffix=".rbl")
        out.parent.mkdir(parents=True, exist_ok=True)  # as rrd does
        return write_blueprint(out, frame=frame, sensing=sensing)
    if not logs:
        raise ConfigError(option("logs"), "no log given", "give run logs or folders of them")
    if rrd is not None:
        check_output(rrd, option("rrd"), suffix=".rrd")
    from wmr.adapters.rerun.replay import replay

    return replay(logs, rrd=rrd, spawn=viewer)


__all__ = ["replay_logs"]

"""A Rerun blueprint that plots a run log as Rerun's own MCAP loader reads it.

Rerun's MCAP loader turns each ``wmr.*`` protobuf message into one struct component
(``wmr.RobotState:message`` with fields ``x_m``, ``v_mps``, ...), which a time series view
does not plot by itself.  This blueprint maps every field of every signal topic onto a
``SeriesLines`` visualizer (a Rerun component mapping with a ``.field`` selector), one time
series view per topic, beside a 3-D view of the poses, so that the log itself shows the
plots without ``wmr replay``.  Steps (``docs/replay.md``)::

    wmr replay --blueprint wmr.rbl
    rerun mcap convert run.mcap --timeline-type duration --application-id wmr-run -o run.rrd
    rerun run.rrd wmr.rbl

``--timeline-type duration`` makes the log times (simulation time, ns from the start) a
duration timeline instead of dates in 1970; ``--application-id`` must be the blueprint's
(:data:`APPLICATION_ID`) for the viewer to apply it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

from wmr.adapters.mcap.schemas import STEP_TOPICS, TORQUE_TOPIC, TopicLayout

#: The application id the blueprint is saved for (``rerun mcap convert --application-id``).
APPLICATION_ID: Final = "wmr-run"
#: The scalar slot of Rerun's ``SeriesLines`` visualizer.
SCALARS: Final = "Scalars:scalars"


def signal_mappings() -> dict[str, list[tuple[str, str]]]:
    """Per signal topic, ``(source component, selector)`` of each plotted field: the struct
    component Rerun's MCAP loader makes of the topic's message, and ``.field``."""
    out: dict[str, list[tuple[str, str]]] = {}
    for layout in (*STEP_TOPICS, TORQUE_TOPIC):
        if layout.signals:
            out[layout.topic] = [(f"{layout.schema_name}:message", f".{s}")
                                 for s in layout.signals]
    return out


def _view(layout_topic: str, pairs: list[tuple[str, str]]) -> object:
    import rerun as rr
    import rerun.blueprint as rrb
    from rerun.blueprint.encodings import ComponentSourceKind, VisualizerComponentMapping

    visualizers = [
        rr.SeriesLines(names=selector[1:]).visualizer(mappings=[VisualizerComponentMapping(
            SCALARS, ComponentSourceKind.SourceComponent, source_component=component,
            selector=selector)])
        for component, selector in pairs]
    return rrb.TimeSeriesView(name=layout_topic, origin=layout_topic,
                              overrides={layout_topic: visualizers})


def write_blueprint(path: str | Path, application_id: str = APPLICATION_ID) -> Path:
    """Write the blueprint to ``path`` (``.rbl``) and return it."""
    import rerun.blueprint as rrb

    views = [_view(topic, pairs) for topic, pairs in signal_mappings().items()]
    blueprint = rrb.Blueprint(rrb.Horizontal(rrb.Spatial3DView(name="poses", origin="/"),
                                             rrb.Grid(*views)))  # type: ignore[arg-type]
    out = Path(path)
    blueprint.save(application_id, out)
    return out


__all__ = ["APPLICATION_ID", "TopicLayout", "signal_mappings", "write_blueprint"]

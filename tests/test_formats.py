"""docs/formats.md and docs/results.md against the code (issue 11, item 3): every table of the
formats is compared with what the code writes and reads, so that neither can drift."""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zipfile
from dataclasses import fields
from pathlib import Path

import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap.schemas import STEP_TOPICS, TORQUE_TOPIC
from wmr.apps.run import run_metadata, run_to_log
from wmr.build.fmus import BuildResult
from wmr.config.scenario import RUN_FIELDS, TOP_FIELDS
from wmr.core.control.stabiliser import Gains, Limits
from wmr.core.plant import Pose, RobotParams
from wmr.core.runspec import RunSpec
from wmr.infra.paths import _REPO_ROOT

DOCS = _REPO_ROOT / "docs"
UNITS = {"_m": "m", "_rad": "rad", "_mps": "m/s", "_radps": "rad/s", "_nm": "N m", "_J": "J"}


def _tables(path: Path) -> dict[str, list[list[str]]]:
    """Markdown tables by their first header cell: rows of cells, backticks stripped."""
    out: dict[str, list[list[str]]] = {}
    lines = path.read_text(encoding="utf-8").splitlines()
    for i, line in enumerate(lines):
        if line.startswith("|") and i + 1 < len(lines) and lines[i + 1].startswith("|---"):
            header = [c.strip() for c in line.strip("|").split("|")]
            rows = []
            for row in lines[i + 2:]:
                if not row.startswith("|"):
                    break
                rows.append([c.strip().replace("`", "") for c in row.strip("|").split("|")])
            out[header[0].replace("`", "")] = rows
    return out


FORMATS = _tables(DOCS / "formats.md")


def _unit(name: str) -> str:
    return next(u for s, u in sorted(UNITS.items(), key=lambda kv: -len(kv[0]))
                if name.endswith(s))


def test_the_topics_and_their_fields_are_the_writers() -> None:
    layouts = (*STEP_TOPICS, TORQUE_TOPIC)
    documented = [(r[0], r[1], r[2]) for r in FORMATS["topic"]]
    assert documented == [(t.topic, t.schema_name,
                           ", ".join(t.signals) if t.signals else "pose of B") for t in layouts]
    signals = [(r[0], r[1], r[2]) for r in FORMATS["field"]]
    assert signals == [(s, t.topic, _unit(s)) for t in layouts for s in t.signals]
    assert all(r[3] for r in FORMATS["field"])  # every field says what it is


def test_the_run_metadata_keys_are_documented(fmu3: Path) -> None:
    documented = {k.strip() for r in FORMATS["run key"] for k in r[0].split(",")}
    with FmuPlant(fmu3) as plant:
        keys = set(run_metadata(RunSpec("a", Pose(0, 0, 0), Pose(1, 0, 0)), plant))
    optional = {"source_file", "sensors", "controller_fmu_file", "controller_fmu_sha256",
                "fmu_map", "log_every_k_steps"}  # only when they apply
    assert documented == keys | optional


def test_the_scenario_fields_and_defaults_are_the_code() -> None:
    assert [r[0] for r in FORMATS["top-level field"]] == list(TOP_FIELDS)
    assert [r[0] for r in FORMATS["run field"]] == list(RUN_FIELDS)
    for cls, table in ((RobotParams, "[params] field"), (Gains, "[gains] field"),
                       (Limits, "[limits] field")):
        rows = FORMATS[table]
        assert [(r[0], float(r[1])) for r in rows] == [(f.name, f.default) for f in fields(cls)]
        assert all(r[2] and r[3] for r in rows)


def test_the_fmu_variables_are_the_model_descriptions(built: BuildResult) -> None:
    for version, fmu in built.fmus.items():
        md = ET.fromstring(zipfile.ZipFile(fmu).read("modelDescription.xml"))
        actual = []
        for v in md.iter("ScalarVariable" if version == 2 else "Float64"):
            if v.get("causality") in ("input", "output", "parameter"):
                unit = v.get("unit")
                if unit is None:
                    real = v.find("Real")
                    unit = real.get("unit") if real is not None else None
                actual.append((v.get("name"), v.get("causality"), unit or ""))
        documented = [(r[0], r[1], r[3]) for r in FORMATS["variable"]]
        assert sorted(documented) == sorted(actual), f"FMI {version}"


def test_the_result_record_keys_are_documented(fmu3: Path, tmp_path: Path) -> None:
    documented = [r[0] for r in _tables(DOCS / "results.md")["key"]]
    spec = RunSpec("a", Pose(0, 0, 0), Pose(1, 0, 0), t_max_s=0.5)
    with FmuPlant(fmu3) as plant:
        record = run_to_log(spec, tmp_path / "a.mcap", plant)
    assert documented == list(record)


@pytest.mark.parametrize("path", ["README.md", *(f"docs/{p.name}" for p in DOCS.glob("*.md"))])
def test_docs_cite_nothing_a_clone_does_not_have(path: str) -> None:
    text = (_REPO_ROOT / path).read_text(encoding="utf-8")
    assert "shared/design" not in text and "errata.md" not in text

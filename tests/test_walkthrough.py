"""Issue 30, "the rest of the same walk-through": defects a new user hit, each pinned here.

Every test was seen failing on the code before its fix (see the commit messages).
"""

from __future__ import annotations

import pytest

from wmr.apps.batch.spec import BATCH_SECTIONS, parse_batch
from wmr.config.scenario import TOP_FIELDS
from wmr.infra.errors import ConfigError

_BASE = {"name": "walk", "start": [0.0, 0.0, 0.0], "goal": [4.0, 2.0, 0.0]}


@pytest.mark.parametrize(("typo", "value", "meant"), [
    ("randm", {"seed": 1, "n": 3}, "random"),
    ("lists", [{"name": "x"}], "list"),
    ("logs", {"keep": "all"}, "log"),
    ("gird", {"params": {"m": [20.0]}}, "grid"),
])
def test_a_misspelled_section_names_every_section_and_the_closest(
        typo: str, value: object, meant: str) -> None:
    """Before: ``randm: unknown field (allowed fields: name, ..., fmu_map)``, the list of a
    plain scenario's fields, without grid, list, random and log."""
    with pytest.raises(ConfigError) as err:
        parse_batch({**_BASE, typo: value})
    assert err.value.field == typo
    assert f"did you mean {meant!r}?" in err.value.fix
    listed = err.value.fix.split("allowed fields: ", 1)[1].split(", ")
    assert listed == [*TOP_FIELDS, *BATCH_SECTIONS]
    assert {"grid", "list", "random", "log"} <= set(listed)


def test_an_unknown_field_far_from_every_name_gets_no_guess() -> None:
    with pytest.raises(ConfigError) as err:
        parse_batch({**_BASE, "grid": {"params": {"zzzz": [1.0]}}})
    assert err.value.field == "grid.params.zzzz"
    assert "did you mean" not in err.value.fix
    assert err.value.fix.startswith("allowed fields: ")


def test_the_fmu_documentation_prints_start_values_as_written() -> None:
    """Before: ``0.14999999999999999`` for a start of 0.15 (``%.17g``) and ``nan`` for the
    outputs, which have no start value."""
    import re

    from wmr.build.documentation import index_html
    from wmr.build.flatten import flatten
    from wmr.infra import paths

    model = flatten(paths.modelica_dir())
    page = index_html(model)
    starts = {v.name: v.start for v in (*model.inputs, *model.outputs, *model.parameters)}
    assert starts["r"] == 0.15  # the case a user saw as 0.14999999999999999
    assert "<td>nan</td>" not in page and "0.14999999999999999" not in page
    for name, start in starts.items():
        row = re.search(rf"<code>{re.escape(name)}</code></td><td>[^<]*</td><td>([^<]*)</td>",
                        page)
        assert row is not None, name
        shown = row.group(1)
        if start != start:  # NaN: no start value
            assert shown == "none", (name, shown)
        else:
            assert float(shown) == start and shown == repr(start), (name, shown)


def test_the_path_of_a_run_without_a_log_warns_how_to_get_it() -> None:
    """Before: ``wmr.run(..., log="none").path`` was an empty DataFrame, without a word."""
    import wmr

    res = wmr.RunResult({"name": "fig11", "status": "converged", "mcap": None}, None)
    with pytest.warns(UserWarning, match=r'log="none".*log="full"') as seen:
        path = res.path
    assert len(seen) == 1 and "'fig11'" in str(seen[0].message)
    assert path.empty and list(path.columns) == ["x_m", "y_m", "theta_rad"]

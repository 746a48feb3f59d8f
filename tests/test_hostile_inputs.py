"""Inputs from strangers (issue 17, part C): parameters, names, journals and FMUs that used to
end in an internal error, a crash or a silently wrong summary.  Each refusal is one line that
names the field or the file."""

from __future__ import annotations

import tomllib

import pytest

from wmr.apps.batch import parse_batch
from wmr.config.scenario import load_scenario, parse_scenario, with_overrides
from wmr.infra.errors import ConfigError

FIG11 = 'name = "h"\nstart = [0.0, 0.0, 0.0]\ngoal = [2.0, 1.0, 0.0]\n'


# -- item 9: a length of 1e308 overflows the mass matrix ------------------------------------------

@pytest.mark.parametrize("name", ["r", "L", "l"])
@pytest.mark.parametrize("route", ["flag", "file", "grid", "random"])
def test_a_huge_length_is_a_config_error_by_every_route(name: str, route: str) -> None:
    """``params.r = 1e308`` used to raise OverflowError from ``r**2`` in the mass matrix."""
    with pytest.raises(ConfigError) as err:
        if route == "flag":
            with_overrides(load_scenario("fig11").runs[0], params={name: 1e308})
        elif route == "file":
            parse_scenario(tomllib.loads(FIG11 + f"[params]\n{name} = 1e308\n"))
        elif route == "grid":
            parse_batch(tomllib.loads(FIG11 + f"[grid.params]\n{name} = [0.2, 1e308]\n"))
        else:
            batch = parse_batch(tomllib.loads(
                FIG11 + f"[random]\nseed = 1\nn = 3\n[random.params]\n{name} = "
                '{ dist = "uniform", low = 1e307, high = 1e308 }\n'))
            list(batch.runs)
    assert f"params.{name}" in str(err.value) and "overflow" in str(err.value)


def test_products_that_overflow_name_the_extreme_parameter() -> None:
    """Each value finite and its square too, but m l^2 is not."""
    with pytest.raises(ConfigError) as err:
        with_overrides(load_scenario("fig11").runs[0], params={"m": 1e300, "l": 1e10})
    assert err.value.field == "params.m"

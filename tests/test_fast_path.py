"""The C stepper (fmu/src/stepper) against the pure-Python master loop: the same bits.

Every run here is made twice on the same FMU, with the stepper (one C call per step, or whole
blocks in C with the controller FMU) and without it (``WMR_STEPPER=0``, the loop that was the
only one before), and must give the same :class:`~wmr.core.closedloop.LoopOutcome` (float
fields compared by their bits) and the same log bytes.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import wmr.core.control.registry as registry
from wmr.adapters import stepper
from wmr.adapters.fmi.compiled_law import CompiledLawController
from wmr.adapters.fmi.controller import FmuController
from wmr.adapters.fmi.robot import FmuPlant
from wmr.apps.run import run_to_log
from wmr.build.fmus import BuildResult, build_stepper
from wmr.config.scenario import Overrides, load_scenario, with_overrides
from wmr.core.closedloop import Controller, LoopOutcome, run_closed_loop
from wmr.core.control.from_spec import SpecController
from wmr.core.runspec import RunSpec


@pytest.fixture(autouse=True)
def fresh_stepper(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Each test loads the stepper anew (the library is cached per process)."""
    stepper._STEPPER.clear()
    yield
    stepper._STEPPER.clear()


def _fig11(**overrides: Any) -> RunSpec:
    return with_overrides(load_scenario("fig11").runs[0], Overrides(**overrides))


def _bits(result: LoopOutcome) -> dict[str, Any]:
    """The result's fields, floats as their bit patterns (NaN equals NaN, -0.0 is not 0.0)."""
    out: dict[str, Any] = {}
    for name, value in dataclasses.asdict(result).items():
        if name == "sensing":
            continue
        if isinstance(value, dict):
            value = tuple(struct.pack("<d", v) for v in value.values())
        elif isinstance(value, float):
            value = struct.pack("<d", value)
        out[name] = value
    return out


#: The loops a run can take: the paper's law compiled into the stepper (whole blocks in C),
#: the Python law with the stepper (one C call per step), and the pure-Python loop.
LOOPS = ("compiled", "stepper", "python")


def _both(monkeypatch: pytest.MonkeyPatch, fmu: Path, spec: RunSpec, log: Path | None,
          controller_fmu: Path | None = None, loops: tuple[str, ...] = LOOPS
          ) -> list[tuple[dict[str, Any], bytes]]:
    """The run in each of ``loops`` (with a controller FMU: with the stepper and without):
    its result's bits and its log's bytes."""
    got = []
    for loop in loops if controller_fmu is None else ("stepper", "python"):
        monkeypatch.setenv("WMR_STEPPER", "0" if loop == "python" else "1")
        with FmuPlant(fmu) as plant:
            plant.reset(spec.params, spec.start)  # instantiated here, with or without
            assert (plant.stepper() is not None) == (loop != "python")
            ctrl = FmuController(controller_fmu) if controller_fmu is not None else None

            def law(loop: str = loop, ctrl: FmuController | None = ctrl) -> Controller:
                if ctrl is not None:
                    return ctrl
                if loop == "compiled":
                    return CompiledLawController()
                return SpecController()

            try:
                if log is None:
                    result = run_closed_loop(spec, plant, controller=law())
                    got.append((_bits(result), b""))
                else:
                    run_to_log(spec, log, plant, controller=law())
                    data = log.read_bytes()
                    log.unlink()
                    result = run_closed_loop(spec, plant, controller=law())
                    got.append((_bits(result), data))
            finally:
                if ctrl is not None:
                    ctrl.close()
    return got


@pytest.mark.parametrize("version", [2, 3])
def test_python_law_converged_run_is_bit_identical_and_its_log_byte_identical(
        monkeypatch: pytest.MonkeyPatch, built: BuildResult, tmp_path: Path,
        version: int) -> None:
    compiled, fast, slow = _both(monkeypatch, built.fmus[version], _fig11(),
                                 tmp_path / "r.mcap")
    assert fast[0]["status"] == "converged" and fast[0]["steps"] == 2672
    assert compiled == fast == slow


def test_controller_fmu_converged_run_is_bit_identical_and_its_log_byte_identical(
        monkeypatch: pytest.MonkeyPatch, built: BuildResult, tmp_path: Path) -> None:
    fast, slow = _both(monkeypatch, built.fmus[3], _fig11(), tmp_path / "r.mcap",
                       built.controllers[3])
    assert fast[0]["status"] == "converged"
    assert fast == slow


@pytest.mark.parametrize("controller", ["pi", "fmu", "astolfi"])
def test_timeout_in_the_middle_of_a_block_is_bit_identical(
        monkeypatch: pytest.MonkeyPatch, built: BuildResult, controller: str) -> None:
    spec = _fig11(max_time_s=2.555)  # 256 steps: the last block is not full
    if controller == "astolfi":
        spec = dataclasses.replace(spec, controller="astolfi")
    *_, fast, slow = _both(monkeypatch, built.fmus[3], spec, None,
                           built.controllers[3] if controller == "fmu" else None)
    assert fast[0]["status"] == "timeout" and fast[0]["steps"] == 257
    assert fast == slow


def test_run_with_sensors_is_bit_identical(monkeypatch: pytest.MonkeyPatch,
                                           built: BuildResult) -> None:
    spec = _fig11(max_time_s=3.0, sensors={"gps_sigma_m": 0.2})
    compiled, fast, slow = _both(monkeypatch, built.fmus[2], spec, None)
    assert compiled == fast == slow


def test_plant_failure_gives_the_same_status_message_and_rows(
        monkeypatch: pytest.MonkeyPatch, built: BuildResult, tmp_path: Path) -> None:
    """A law that asks for a NaN wheel speed at step 150: the FMU refuses the NaN torque."""
    make = registry.make_controller

    class NanAt151:
        def __init__(self, law: Any) -> None:
            self.law, self.calls = law, 0
            self.converged, self.heading_error = law.converged, law.heading_error

        def update(self, x: float, y: float, theta: float) -> tuple[float, ...]:
            self.calls += 1
            sig = self.law.update(x, y, theta)
            return (*sig[:12], math.nan, *sig[13:]) if self.calls == 151 else sig

    def failing(*args: Any) -> Any:
        ctrl = make(*args)
        ctrl.stabiliser = NanAt151(ctrl.stabiliser)
        return ctrl

    # the run's own law is built by SpecController.configure, at every run
    monkeypatch.setattr(registry, "make_controller", failing)
    fast, slow = _both(monkeypatch, built.fmus[3], _fig11(), tmp_path / "r.mcap",
                       loops=("stepper", "python"))
    assert fast[0]["status"] == "failed"
    assert "FmuError at t = 1.5 s: fmi3SetFloat64 returned Error" in fast[0]["message"]
    assert fast == slow


def test_without_a_compiler_the_python_path_runs(monkeypatch: pytest.MonkeyPatch,
                                                 built: BuildResult) -> None:
    import wmr.build.fmus

    monkeypatch.setattr(wmr.build.fmus, "build_stepper", lambda *a, **k: None)
    assert stepper.load_stepper() is None
    with FmuPlant(built.fmus[3]) as plant:
        result = run_closed_loop(_fig11(max_time_s=1.0), plant, controller=SpecController())
        assert plant.stepper() is None
    assert result.status == "timeout" and result.steps == 101


def test_the_stepper_is_rebuilt_when_its_source_changes(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """A change in any file of the stepper (here a part that wmr_stepper.c includes, not the
    file the compiler is given) is a new library."""
    import shutil

    from wmr.build.fmus import stepper_source

    out = tmp_path / "out"
    out.mkdir()
    first = build_stepper(out)
    assert first is not None and first.exists()
    assert build_stepper(out) == first  # reused
    src = tmp_path / "stepper"
    shutil.copytree(stepper_source().parent, src)
    monkeypatch.setattr("wmr.build.fmus.stepper_source", lambda: src / "wmr_stepper.c")
    assert build_stepper(out) == first  # the same sources elsewhere: the same library
    part = src / "encode.c"
    part.write_text(part.read_text() + "\n/* changed */\n")
    second = build_stepper(out)
    assert second is not None and second != first


def test_fmu_plant_step_through_the_stepper_matches_the_three_calls(
        monkeypatch: pytest.MonkeyPatch, built: BuildResult) -> None:
    spec = _fig11()
    outputs = []
    for mode in ("1", "0"):
        monkeypatch.setenv("WMR_STEPPER", mode)
        with FmuPlant(built.fmus[2]) as plant:
            plant.reset(spec.params, spec.start)
            rows = [plant.step(0.5 * math.sin(k), -0.3, 0.01).tobytes() for k in range(50)]
            outputs.append((rows, plant.time_s))
    assert outputs[0] == outputs[1]


def test_the_hot_path_wrap_is_wrap_then_unwrap_bit_for_bit() -> None:
    """PointStabiliser.update's one-call ``_wrapped_near`` against the two public functions
    it replaces, on every band edge and on random angles and previous values."""
    import random

    from wmr.core.control.stabiliser import (
        HYSTERESIS_BAND_RAD,
        _wrapped_near,
        unwrap_near,
        wrap_angle,
    )

    rng = random.Random(5)
    edges = [0.0, -0.0, math.pi, -math.pi, 2 * math.pi, math.pi - HYSTERESIS_BAND_RAD,
             HYSTERESIS_BAND_RAD - math.pi, math.nan, 1e300, -1e300]
    angles = edges + [math.nextafter(e, s) for e in edges for s in (-math.inf, math.inf)]
    angles += [rng.uniform(-20.0, 20.0) for _ in range(20000)]
    for a in angles:
        for prev in (0.0, -0.0, 1.0, -1.0, rng.uniform(-4.0, 4.0)):
            assert struct.pack("<d", _wrapped_near(a, prev)) == \
                struct.pack("<d", unwrap_near(wrap_angle(a), prev)), (a, prev)


def test_compiled_law_runs_the_monte_carlo_with_the_python_law_s_bits(
        monkeypatch: pytest.MonkeyPatch, built: BuildResult, tmp_path: Path) -> None:
    """Six runs of the Fig. 10 Monte Carlo (random starts all around the goal, goal headings
    of 0 and 180 deg, random mass, centre of gravity, inertia and friction feed-forward): the
    compiled law gives the Python law's results and log bytes, and it did run in C."""
    from wmr.apps.batch.spec import load_batch

    runs = [run.spec for run in load_batch("mc_fig10").runs[:6]]
    used = []
    real = CompiledLawController.block_loop

    def spy(self: CompiledLawController, *args: Any) -> Any:
        used.append(self)
        return real(self, *args)

    monkeypatch.setattr(CompiledLawController, "block_loop", spy)
    for spec in runs:
        compiled, fast = _both(monkeypatch, built.fmus[3], spec, tmp_path / "r.mcap",
                               loops=("compiled", "stepper"))
        assert compiled[0]["status"] in ("converged", "timeout"), spec.name
        assert compiled == fast, spec.name
    assert len(used) == 2 * len(runs)  # the log's run and the result's run, each in C


def test_compiled_law_agrees_with_the_python_law_on_many_states() -> None:
    """20,000 random states (both phases, across the angle wrap, random goals, gains and
    friction): every output and next state of the compiled law is the Python law's."""
    from wmr.adapters.fmi.compiled_law import compiled_law_agrees

    lib = stepper.load_stepper()
    assert lib is not None
    assert compiled_law_agrees(lib, n_states=20_000, seed=7)


def test_a_compiled_law_that_disagrees_in_one_bit_is_not_used(
        monkeypatch: pytest.MonkeyPatch, built: BuildResult) -> None:
    """A library whose hypot is one ulp off on one pair (another Python's math.hypot, say) is
    refused by the self-check, and the runs take the Python law with the stepper."""
    import ctypes

    from wmr.adapters.fmi import compiled_law

    real = stepper.load_stepper()
    assert real is not None

    class OneUlpOff:
        _name = "one-ulp-off"

        def __getattr__(self, name: str) -> Any:
            return getattr(real, name)

        def __init__(self) -> None:
            self.calls = 0
            hypot = real.wmr_law_hypot

            def off(a: float, b: float) -> float:
                self.calls += 1
                h = float(hypot(ctypes.c_double(a), ctypes.c_double(b)))
                return math.nextafter(h, math.inf) if self.calls == 300 else h

            self.wmr_law_hypot = off

    fake = OneUlpOff()
    assert not compiled_law.compiled_law_agrees(fake)
    monkeypatch.setattr(compiled_law, "load_stepper", lambda build=True: OneUlpOff())
    ctrl = CompiledLawController()
    ctrl.configure(_fig11())
    assert ctrl.stepper_kind == "servo"


@pytest.mark.parametrize("change", [{"controller": "astolfi"},
                                    {"sensors": {"gps_sigma_m": 0.2}}])
def test_the_compiled_law_is_only_the_paper_s_law_without_sensors(change: dict[str, Any]
                                                                   ) -> None:
    spec = _fig11()
    assert stepper.load_stepper() is not None
    ctrl = CompiledLawController()
    ctrl.configure(spec)
    assert ctrl.stepper_kind == "blocks"
    if "controller" in change:
        spec = dataclasses.replace(spec, **change)
    else:
        spec = _fig11(**change)
    ctrl.configure(spec)
    assert ctrl.stepper_kind == "servo"

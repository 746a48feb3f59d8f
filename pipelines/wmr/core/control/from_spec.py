"""The run's own Python controller: the law a :class:`~wmr.core.runspec.RunSpec` names.

:class:`SpecController` is what a caller of :func:`wmr.core.closedloop.run_closed_loop` hands
the loop when the run has no controller FMU: at :meth:`SpecController.configure` it builds the
spec's law afresh (``spec.controller``: any controller of :mod:`wmr.core.control.registry`, the
paper's PI stabiliser, a peer or a plug-in, with the spec's goal, gains, limits, robot, period
and the controller's own gains; :func:`wmr.core.control.registry.make_controller`)
and takes on its ``step``, ``stabiliser`` and wheel servos, so that the loop calls the law's
own methods, without a forwarding call per step.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from wmr.core.control import registry

if TYPE_CHECKING:
    from wmr.core.control import ServoedController, Stabiliser, WheelServo
    from wmr.core.runspec import RunSpec


class SpecController:
    """The Python controller of whichever run it is configured with (the loop's
    :class:`~wmr.core.closedloop.Controller`).

    One instance serves any number of runs: each :meth:`configure` builds the law of that run
    anew, as if the controller were new.
    """

    #: The C stepper may run the wheel servos (``wmr.core.closedloop``, "The C stepper").
    stepper_kind: str = "servo"

    def __init__(self) -> None:
        self.law: ServoedController | None = None

    def configure(self, spec: RunSpec) -> None:
        """Build the law of ``spec`` (``spec.controller`` with its gains), fresh."""
        law = registry.make_controller(spec)
        self.law = law
        # the law's own bound method: the loop's per-step call reaches it directly
        self.step = law.step  # type: ignore[method-assign]

    def step(self, x: float, y: float, theta: float, omega_r: float,
             omega_l: float) -> tuple[float, ...]:
        """One control period (the law's :meth:`~wmr.core.control.ServoedController.step`,
        once :meth:`configure` has built it)."""
        raise RuntimeError("SpecController.step before configure(spec)")

    def _built(self) -> ServoedController:
        if self.law is None:
            raise RuntimeError("SpecController used before configure(spec)")
        return self.law

    @property
    def stabiliser(self) -> Stabiliser:
        """The law's stabiliser (``converged``, ``heading_error``, ``update``)."""
        return self._built().stabiliser

    @property
    def right(self) -> WheelServo:
        """The right wheel's servo."""
        return self._built().right

    @property
    def left(self) -> WheelServo:
        """The left wheel's servo."""
        return self._built().left


__all__ = ["SpecController"]

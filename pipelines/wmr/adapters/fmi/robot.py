"""The FMU as a :class:`wmr.core.plant.Plant`: one instance, reset per run, fast per step.

The instance is a :class:`wmr.adapters.fmi.slave.FmuSlave` (extraction, FMI 2 or 3, statuses,
the Fatal rule), as the controller FMU's is: fmpy's wrappers raise
``fmpy.fmi1.FMICallException`` on an error status, which becomes an
:class:`wmr.infra.errors.FmuError` naming the function.  The per-step path holds prebuilt ctypes
arrays for the value references, the inputs and the outputs, so a step allocates nothing and
looks nothing up; with the C stepper (:func:`wmr.adapters.stepper.load_stepper`) the three
calls of a step are one C call.

A robot FMU made by another tool is driven through a variable map
(:mod:`wmr.adapters.fmi.varmap`): the value references are the FMU's, and the inputs, outputs and
parameters pass through ``ours = scale * theirs + offset`` on the way.  Without a map (or with
one whose outputs all keep their unit) the outputs are the ctypes array itself.
"""

from __future__ import annotations

import ctypes
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wmr.adapters.fmi.archive import file_sha256
from wmr.adapters.fmi.slave import WARNING, FmuSlave
from wmr.adapters.fmi.varmap import VariableMap, resolve
from wmr.adapters.stepper import FmuCall, load_stepper
from wmr.adapters.stepper.loops import fast_loop
from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams
from wmr.infra.errors import ConfigError, FmuError


def fmu_call(fmi_version: str, dll: Any, component: Any, names: tuple[str, str, str],
             in_vr: Any, in_val: Any, out_vr: Any, out_val: Any) -> FmuCall:
    """The stepper's view of an instance: the FMU's own ``set``, ``doStep`` and ``get``."""
    call = FmuCall()
    call.fmi_version = 2 if fmi_version.startswith("2") else 3
    call.n_in, call.n_out = len(in_vr), len(out_vr)
    call.instance = component
    call.set, call.do_step, call.get = (ctypes.cast(getattr(dll, n), ctypes.c_void_p).value
                                        for n in names)
    call.in_vr, call.in_val = ctypes.addressof(in_vr), ctypes.addressof(in_val)
    call.out_vr, call.out_val = ctypes.addressof(out_vr), ctypes.addressof(out_val)
    call.in_gain[0] = call.in_gain[1] = 1.0
    return call


class FmuPlant:
    """Drive a co-simulation FMU of the robot (FMI 2.0 or 3.0) through fmpy.

    Parameters
    ----------
    fmu_path
        The ``.fmu`` file.
    instance_name
        Name given to the FMU instance (shows in its log messages).
    var_map
        How our interface names map to the FMU's variables (:mod:`wmr.adapters.fmi.varmap`);
        ``None``: the FMU has our names and units.
    """

    def __init__(self, fmu_path: str | Path, instance_name: str = "robot",
                 var_map: VariableMap | None = None) -> None:
        self.fmu_path = Path(fmu_path)
        self._slave = slave = FmuSlave(self.fmu_path, instance_name)
        md = slave.model_description
        if md.coSimulation is None:
            slave.remove_folder()
            raise FmuError(f"{self.fmu_path}: not a co-simulation FMU")
        self.model_description = md
        #: ``modelDescription.xml`` of the instance, as extracted (a log's attachment).
        self.model_description_xml: bytes = slave.model_description_xml
        self.fmi_version = slave.fmi_version
        self.sha256 = file_sha256(self.fmu_path)
        try:
            self._map = resolve(var_map, md, self.fmu_path.name)
        except ConfigError:
            slave.remove_folder()
            raise
        self.var_map = var_map
        self._t = self._t0 = self._h = 0.0
        self._n = 0
        self._make_arrays()

    def _make_arrays(self) -> None:
        vr_type = ctypes.c_uint32
        rm = self._map
        self._in_vr = (vr_type * 2)(*(vr for vr, _ in rm.inputs))
        self._in_val = (ctypes.c_double * 2)()
        # theirs = ours * gain + bias for the two torques
        (_, e_r), (_, e_l) = rm.inputs
        self._in_names = (e_r.name, e_l.name)  # the FMU's names of tau_r and tau_l
        self._in_gain_r, self._in_bias_r = 1.0 / e_r.scale, -e_r.offset / e_r.scale
        self._in_gain_l, self._in_bias_l = 1.0 / e_l.scale, -e_l.offset / e_l.scale
        present = [(i, o) for i, o in enumerate(rm.outputs) if o is not None]
        self._n_out = len(present)
        self._out_vr = (vr_type * self._n_out)(*(o[0] for _, o in present))
        self._out_val = (ctypes.c_double * self._n_out)()
        raw: npt.NDArray[np.float64] = np.ctypeslib.as_array(self._out_val)
        self._raw_out = raw
        self._outputs: npt.NDArray[np.float64]
        if rm.identity:
            self._outputs = raw
            self._convert = False
        else:
            self._outputs = np.full(len(OUTPUT_NAMES), np.nan)
            self._out_idx = np.array([i for i, _ in present], dtype=np.intp)
            self._out_scale = np.array([o[1].scale for _, o in present])
            self._out_offset = np.array([o[1].offset for _, o in present])
            self._convert = True

    def _get_outputs(self) -> None:
        """Read the outputs into :attr:`_outputs`, in our names' order and units."""
        self._check(2, self._slave.raw_get())
        if self._convert:
            self._outputs[self._out_idx] = self._raw_out * self._out_scale + self._out_offset

    def _bind_hot_path(self) -> None:
        """The three calls of a step, bound once to the instance and the prebuilt arrays
        (:meth:`FmuSlave.bind`), and this instance as the C stepper sees it, when it is
        there."""
        slave = self._slave
        slave.bind(self._in_vr, self._in_val, self._out_vr, self._out_val)
        self._fast: Any = None
        lib = load_stepper()
        if lib is not None:
            call = fmu_call(self.fmi_version, slave.fmu.dll, slave.fmu.component, slave.names,
                            self._in_vr, self._in_val, self._out_vr, self._out_val)
            call.in_gain[0], call.in_bias[0] = self._in_gain_r, self._in_bias_r
            call.in_gain[1], call.in_bias[1] = self._in_gain_l, self._in_bias_l
            self.fmu_call = call
            self._call_ref = ctypes.byref(call)
            self._fast = partial(lib.wmr_exchange, self._call_ref)

    def _check(self, which: int, status: int) -> None:
        """Raise for a status above fmiWarning of call ``which`` (0 set, 1 step, 2 get)."""
        if status <= WARNING:
            return
        raise self._slave.status_error(
            which, status, self._t, f"{self._in_names[0]} = {self._in_val[0]!r}, "
            f"{self._in_names[1]} = {self._in_val[1]!r}")

    def reset(self, params: RobotParams, start: Pose, v0_mps: float = 0.0,
              omega0_radps: float = 0.0) -> npt.NDArray[np.float64]:
        """Start a run at t = 0 from ``start`` with ``params``; return the outputs at t = 0."""
        slave = self._slave
        if slave.instantiate_or_reset(at_s=self._t):
            self._bind_hot_path()
        values = params.as_dict()
        values.update(x0=start.x_m, y0=start.y_m, theta0=start.heading_rad, v0=v0_mps,
                      omega0=omega0_radps)
        vrs, theirs = self._parameter_values(values)
        self._t, self._t0, self._h, self._n = 0.0, 0.0, 0.0, 0
        slave.enter_initialization(at_s=self._t)
        slave.set_float64(f"setting the parameters {values}", vrs, theirs)
        self._in_val[0] = self._in_bias_r
        self._in_val[1] = self._in_bias_l
        self._check(0, slave.raw_set())
        slave.exit_initialization(at_s=self._t)
        self._get_outputs()
        return self._outputs

    def _parameter_values(self, values: dict[str, float]) -> tuple[list[int], list[float]]:
        """Value references and the FMU's values of our parameters ``values`` (those it has).

        A parameter the map leaves unmapped keeps the FMU's own value.
        """
        params = self._map.parameters
        vrs = [params[n][0] for n in values if n in params]
        theirs = [params[n][1].to_theirs(v) for n, v in values.items() if n in params]
        return vrs, theirs

    def step(self, tau_r_nm: float, tau_l_nm: float, h_s: float) -> npt.NDArray[np.float64]:
        """Hold the torques for ``h_s`` seconds; the returned array is reused by the next step."""
        if self._fast is not None:  # the same three calls, made by the C stepper
            code = self._fast(tau_r_nm, tau_l_nm, self._t, h_s)
            if code:
                self.raise_step_error(code)
            if self._convert:
                self._outputs[self._out_idx] = (self._raw_out * self._out_scale
                                                + self._out_offset)
        else:
            self._in_val[0] = tau_r_nm * self._in_gain_r + self._in_bias_r
            self._in_val[1] = tau_l_nm * self._in_gain_l + self._in_bias_l
            # a failed call raises; the outputs keep their last good values
            slave = self._slave
            self._check(0, slave.raw_set())
            self._check(1, slave.raw_step(self._t, h_s))
            self._get_outputs()
        # Time is t0 + n*h while h stays the same (never t += h): no drift over long runs.
        if h_s != self._h:
            self._t0, self._h, self._n = self._t, h_s, 0
        self._n += 1
        self._t = self._t0 + self._n * h_s
        return self._outputs

    def raise_step_error(self, code: int) -> None:
        """Raise the :class:`FmuError` of a stepper status ``16 * (call + 1) + status``."""
        self._check(code // 16 - 1, code % 16)

    def stepper(self) -> tuple[Any, FmuCall] | None:
        """The C stepper and this instance's view for it, when both are there and the outputs
        need no conversion (a mapped FMU with other units steps through :meth:`step`)."""
        if self._fast is None or self._convert:
            return None
        return load_stepper(build=False), self.fmu_call

    def fast_loop(self, controller: Any, sensing: Any) -> Any:
        """The C stepper's loop for ``controller`` (:func:`wmr.adapters.stepper.loops.fast_loop`,
        a :class:`wmr.core.closedloop.FastLoop`), or None: the core's Python loop runs."""
        return fast_loop(self, self.stepper(), controller, sensing)

    def set_clock(self, h_s: float, n: int) -> None:
        """The clock after ``n`` steps of ``h_s`` from t = 0 taken by the stepper, as
        :meth:`step` would have left it."""
        self._t0, self._h, self._n = 0.0, h_s, n
        self._t = self._t0 + n * h_s

    @property
    def time_s(self) -> float:
        """The communication point the FMU is at."""
        return self._t

    def outputs(self) -> dict[str, float]:
        """The current outputs by FMU name."""
        return dict(zip(OUTPUT_NAMES, self._outputs.tolist(), strict=True))

    def set_parameters(self, **values: float) -> None:
        """Change tunable parameters (e.g. ``m`` for a load change) between steps."""
        unknown = [n for n in values if n not in self._map.parameters]
        if unknown:
            raise ConfigError(f"parameter {unknown[0]}", f"{self.fmu_path.name} has no "
                              "such parameter (or the map leaves it unmapped)",
                              "set one of: " + ", ".join(self._map.parameters))
        vrs, theirs = self._parameter_values(dict(values))
        self._slave.set_float64(f"setting {values}", vrs, theirs, at_s=self._t)

    def get_state(self) -> tuple[Any, float, float, float, int]:
        """Snapshot of the FMU state and of the master's clock (FMI get FMU state)."""
        return (self._slave.get_fmu_state(at_s=self._t), self._t, self._t0, self._h, self._n)

    def set_state(self, snapshot: tuple[Any, float, float, float, int]) -> None:
        """Go back to a snapshot of :meth:`get_state`."""
        self._slave.set_fmu_state(snapshot[0], at_s=self._t)
        self._t, self._t0, self._h, self._n = snapshot[1:]
        self._get_outputs()

    def serialize_state(self, snapshot: tuple[Any, float, float, float, int]) -> bytes:
        """Bytes of a snapshot's FMU state (FMI serialize FMU state)."""
        return self._slave.serialize_fmu_state(snapshot[0], at_s=self._t)

    def deserialize_state(self, blob: bytes, clock: tuple[float, float, float, int]
                          ) -> tuple[Any, float, float, float, int]:
        """A snapshot from bytes of :meth:`serialize_state` and the clock it was taken at."""
        return (self._slave.deserialize_fmu_state(blob, at_s=self._t), *clock)

    def close(self) -> None:
        """Terminate and free the instance and remove the extraction folder
        (:meth:`FmuSlave.close`: nothing is called after a Fatal status)."""
        self._slave.close()

    def __enter__(self) -> FmuPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

"""The C stepper behind one door: its host library, loaded and checked, and the ctypes views
of the structs it shares with Python.

The stepper (``fmu/src/stepper/``: ``wmr_stepper.c`` and the parts it includes, the FMU
exchange and block loops, the paper's law compiled in, the log's record encoding) is built by
:func:`wmr.build.fmus.build_stepper` beside the FMUs, with the host's C compiler.  This module is
the only one that loads it (:func:`load_stepper`) and the only one that mirrors its structs
(:class:`FmuCall`, :class:`LoopState`, :class:`LawCall`, :class:`Layout`): each is checked field
by field against the one header, ``fmu/src/stepper/wmr_stepper.h``, by ``tests/test_stepper.py``,
so that a field added in C cannot be missed here.  Its users (the FMU plant and controllers,
the compiled law, the log writer) take the library and the views from here.
"""

from __future__ import annotations

import ctypes
import os
import sys
from typing import Any, Final

from wmr.infra.errors import WmrError

# -- the views of wmr_stepper.h ------------------------------------------------------------------


class FmuCall(ctypes.Structure):
    """One FMU instance and its prebuilt exchange arrays (``wmr_fmu``)."""

    _fields_ = [("fmi_version", ctypes.c_int), ("n_in", ctypes.c_int),
                ("n_out", ctypes.c_int), ("pad", ctypes.c_int),
                ("instance", ctypes.c_void_p), ("set", ctypes.c_void_p),
                ("do_step", ctypes.c_void_p), ("get", ctypes.c_void_p),
                ("in_vr", ctypes.c_void_p), ("out_vr", ctypes.c_void_p),
                ("in_val", ctypes.c_void_p), ("out_val", ctypes.c_void_p),
                ("in_gain", ctypes.c_double * 2), ("in_bias", ctypes.c_double * 2)]


class LoopState(ctypes.Structure):
    """What the stepper keeps of a run (``wmr_loop``): the wheel servos, the accumulators, the
    clock and the row of the block being written."""

    _fields_ = [*((name, ctypes.c_double) for name in (
        "k_p", "k_i", "torque_max", "h_servo", "b_ff", "tau_c_ff", "w_c", "k_t",
        "integral_r", "integral_l", "energy_net", "energy_pos", "tau_sq", "peak", "h",
        "path", "x_prev", "y_prev")),
        ("n", ctypes.c_longlong), ("n_max", ctypes.c_longlong),
        ("block", ctypes.c_void_p),
        *((name, ctypes.c_int) for name in (
            "n_cols", "row", "rows_max", "n_plant", "n_sig", "col_tau_r", "col_tau_l",
            "i_converged"))]


class LawCall(ctypes.Structure):
    """One run of the compiled law (``wmr_law``): parameters, discrete state, goal heading and
    tolerance in rad."""

    _fields_ = [("p", ctypes.c_void_p), ("z", ctypes.c_void_p),
                ("theta_d", ctypes.c_double), ("tol", ctypes.c_double)]


class Layout(ctypes.Structure):
    """The per-step topics' channels, bodies and slots of the record encoder (``wmr_layout``)."""

    _fields_ = [("n_sig", ctypes.c_int), ("n_extra", ctypes.c_int), ("n_topics", ctypes.c_int),
                *((name, ctypes.c_void_p) for name in (
                    "channel", "body_len", "bodies", "n_slots", "slot_off", "slot_src"))]


#: The views by the name of their C struct (what the header check walks).
VIEWS: Final[dict[str, type[ctypes.Structure]]] = {
    "wmr_fmu": FmuCall, "wmr_loop": LoopState, "wmr_law": LawCall, "wmr_layout": Layout}

#: Status codes of the stepper besides a failed FMI call's ``16 * (call + 1) + status``
#: (``WMR_CTRL``, ``WMR_NONFINITE``, ``WMR_DONE``, ``WMR_FULL`` of the header).
STEP_CONTROLLER: Final = 64
STEP_NONFINITE: Final = 256
STEP_DONE: Final = 512
STEP_FULL: Final = 1024

# -- the library ----------------------------------------------------------------------------------

_STEPPER: list[Any] = []


def _say(line: str) -> None:
    """One warning line on stderr (stdout is for results, ``--json``)."""
    print(f"wmr: warning: {line}", file=sys.stderr, flush=True)


def load_stepper(build: bool = True) -> Any:
    """The C stepper library (ctypes), loaded once per process; None when it cannot be had.

    ``build``: compile it first if it is not built (what an FMU plant asks when it is opened,
    before any run, and ``build_fmus`` does beside the FMUs); False: only a library built
    before, else None without a word (what the log writer and the compiled law ask in the
    middle of a run: they then take their pure-Python path, the same bytes and bits).

    Only a library :func:`wmr.build.fmus.build_stepper` built or checked is loaded (a cache
    folder others can write is refused there).  A refused folder, a library that does not
    load or lacks a function: one warning line on stderr, then the pure-Python path (the same
    results), never silently.

    ``WMR_STEPPER=0`` in the environment turns it off (the pure-Python path, same results).
    """
    if os.environ.get("WMR_STEPPER", "1") == "0":
        return None
    if not _STEPPER:
        lib: Any = None
        path = None
        try:
            from wmr.build.fmus import build_stepper

            path = build_stepper(progress=_say, compile_now=build)
            if path is None and not build:
                return None  # not built yet: the next load that may build will
            if path is not None:
                lib = _bind_stepper(ctypes.CDLL(str(path)))
        except WmrError as exc:
            _say(f"the C stepper is not used (the pure-Python path runs, same results): {exc}")
            lib = None
        except (OSError, AttributeError) as exc:  # a library that does not load, or lacks one
            _say(f"the C stepper {path} is not used (the pure-Python path runs, same "
                 f"results): {exc}; remove it to have it built again")
            lib = None
        _STEPPER.append(lib)
    return _STEPPER[0]


def _bind_stepper(lib: Any) -> Any:
    """``lib`` with the prototypes of the stepper's functions (AttributeError if one is
    missing); the law's are bound and checked by :mod:`wmr.adapters.fmi.compiled_law`."""
    ptr = ctypes.POINTER
    lib.wmr_exchange.argtypes = [ptr(FmuCall), ctypes.c_double, ctypes.c_double,
                                 ctypes.c_double, ctypes.c_double]
    lib.wmr_servo_step.argtypes = [ptr(FmuCall), ptr(LoopState), ctypes.c_double,
                                   ctypes.c_double, ctypes.c_int]
    lib.wmr_fmu_loop.argtypes = [ptr(FmuCall), ptr(FmuCall), ptr(LoopState)]
    for fun in (lib.wmr_exchange, lib.wmr_servo_step, lib.wmr_fmu_loop):
        fun.restype = ctypes.c_int
    lib.wmr_encode_rows.argtypes = [ctypes.c_int, *[ctypes.c_void_p] * 2,
                                    *[ctypes.c_int] * 2, *[ctypes.c_void_p] * 8]
    lib.wmr_encode_rows.restype = ctypes.c_longlong
    lib.wmr_encode_chunk.argtypes = [ctypes.c_void_p, ctypes.c_int, *[ctypes.c_void_p] * 5]
    lib.wmr_encode_chunk.restype = ctypes.c_longlong
    return lib


__all__ = ["STEP_CONTROLLER", "STEP_DONE", "STEP_FULL", "STEP_NONFINITE", "VIEWS", "FmuCall",
           "LawCall", "Layout", "LoopState", "load_stepper"]

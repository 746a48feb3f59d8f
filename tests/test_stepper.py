"""The C stepper's one door (wmr.adapters.stepper): its ctypes views are its header's structs,
field by field, and its status codes the header's; the loops it runs for an FMU plant are
in the adapter, and the core sees only a protocol."""

from __future__ import annotations

import ctypes
import re
from pathlib import Path

import pytest

from wmr.adapters import stepper
from wmr.infra.paths import fmu_src_dir

HEADER = fmu_src_dir() / "stepper" / "wmr_stepper.h"

#: ``typedef struct { ... } name;`` of the header, and a field line: ``type name;`` or ``type
#: name[N];``, a comment after it if any (the header's own format rule).
_STRUCT = re.compile(r"typedef struct \{\n(.*?)\n\} (\w+);", re.S)
_FIELD = re.compile(r"^\s*((?:const )?(?:unsigned )?(?:long long|int|double|char|void))"
                    r"\s*(\*?)\s*(\w+)(?:\[(\d+)\])?;\s*(?:/\*.*\*/)?\s*$")
_C_TYPES = {"int": ctypes.c_int, "long long": ctypes.c_longlong, "double": ctypes.c_double}


def header_structs(text: str) -> dict[str, list[tuple[str, object]]]:
    """Each struct of the header: its fields as ``(name, ctypes type)``, a pointer as
    ``c_void_p`` (the views hold addresses), an array as ``type * N``."""
    out: dict[str, list[tuple[str, object]]] = {}
    for body, name in _STRUCT.findall(text):
        fields: list[tuple[str, object]] = []
        for line in body.splitlines():
            if not line.strip():
                continue
            m = _FIELD.match(line)
            assert m, f"{name}: a field line the check cannot read (one field a line): {line!r}"
            c_type, pointer, field, length = m.groups()
            base = c_type.removeprefix("const ").removeprefix("unsigned ")
            kind: object = ctypes.c_void_p if pointer else _C_TYPES[base]
            if length:
                kind = (kind, int(length))
            fields.append((field, kind))
        out[name] = fields
    return out


def view_fields(view: type[ctypes.Structure]) -> list[tuple[str, object]]:
    """A view's ``_fields_`` in the form of :func:`header_structs`."""
    out: list[tuple[str, object]] = []
    for name, kind in view._fields_:
        if issubclass(kind, ctypes.Array):
            out.append((name, (kind._type_, kind._length_)))
        else:
            out.append((name, kind))
    return out


def test_every_view_is_its_header_struct_field_by_field() -> None:
    """Names, order and types of every struct of wmr_stepper.h against its ctypes view: a
    field added, removed, renamed, moved or retyped on one side fails here."""
    structs = header_structs(HEADER.read_text())
    assert set(structs) == set(stepper.VIEWS), "a struct without a view, or a view without one"
    for name, view in stepper.VIEWS.items():
        assert view_fields(view) == structs[name], name


def test_the_check_sees_a_field_missing_from_a_view() -> None:
    """The check itself, on a header with one more field than the view has (as a field added
    in C and forgotten in Python would be)."""
    text = HEADER.read_text().replace("    int i_converged;\n",
                                      "    int i_converged;\n    double added_in_c;\n")
    assert text != HEADER.read_text()
    planted = header_structs(text)
    assert view_fields(stepper.LoopState) != planted["wmr_loop"]
    assert view_fields(stepper.LoopState) == planted["wmr_loop"][:-1]


def test_status_codes_are_the_headers() -> None:
    defines = dict(re.findall(r"#define (WMR_\w+) (\d+)", HEADER.read_text()))
    assert (int(defines["WMR_CTRL"]), int(defines["WMR_NONFINITE"]), int(defines["WMR_DONE"]),
            int(defines["WMR_FULL"])) == (stepper.STEP_CONTROLLER, stepper.STEP_NONFINITE,
                                          stepper.STEP_DONE, stepper.STEP_FULL)


def test_the_library_has_every_function_the_header_declares() -> None:
    """Each ``WMR_API`` function of the header is exported by the built library (the
    adapter binds them, the law's in :mod:`wmr.adapters.fmi.compiled_law`)."""
    lib = stepper.load_stepper()
    if lib is None:
        pytest.skip("no C compiler: the pure-Python path runs")
    declared = re.findall(r"^WMR_API [\w ]+?\**(wmr_\w+)\(", HEADER.read_text(), re.M)
    assert len(declared) >= 9
    for name in declared:
        assert hasattr(lib, name), name


def test_the_core_holds_no_part_of_the_c_fast_path() -> None:
    """The core's loop takes a plant's FastLoop; the ctypes views and the loops that use them
    are the adapter's (import-linter forbids ctypes in wmr.core: pyproject.toml)."""
    import wmr.core.closedloop as core

    for name in ("LoopState", "STEP_FULL", "_servo_loop", "_fmu_loop", "_stepper"):
        assert not hasattr(core, name), name
    text = Path(core.__file__).read_text()
    assert "ctypes" not in text and "set_clock" not in text and "raise_step_error" not in text


def test_the_fast_loop_is_chosen_only_where_it_gives_the_python_loops_bits() -> None:
    """``adapters.stepper.loops.fast_loop``: whole blocks in C for a ``"blocks"`` controller
    without sensors, one C call per step for a ``"servo"`` law on two real ``WheelServo`` s,
    and the core's Python loop (None) otherwise: no library, a plant whose outputs are not
    ours, a ``"blocks"`` controller with sensors (the C loop takes the true state only), a
    servo of another class. Seen failing with the sensing condition dropped."""
    from types import SimpleNamespace

    from wmr.adapters.stepper.loops import fast_loop
    from wmr.core.control import WheelServo
    from wmr.core.signals import PLANT_SIGNALS

    lib, call = object(), SimpleNamespace(n_out=len(PLANT_SIGNALS))
    servo = WheelServo.__new__(WheelServo)
    blocks = SimpleNamespace(stepper_kind="blocks")
    law = SimpleNamespace(stepper_kind="servo", right=servo, left=servo)
    sensing = object()
    assert fast_loop(None, (lib, call), blocks, None) is not None
    assert fast_loop(None, (lib, call), law, None) is not None
    assert fast_loop(None, (lib, call), law, sensing) is not None  # the law runs in Python
    assert fast_loop(None, None, blocks, None) is None
    assert fast_loop(None, (None, call), blocks, None) is None
    assert fast_loop(None, (lib, SimpleNamespace(n_out=3)), blocks, None) is None
    assert fast_loop(None, (lib, call), blocks, sensing) is None

    class OtherServo(WheelServo):
        pass

    other = OtherServo.__new__(OtherServo)
    assert fast_loop(None, (lib, call), SimpleNamespace(stepper_kind="servo", right=other,
                                                        left=servo), None) is None
    assert fast_loop(None, (lib, call), SimpleNamespace(), None) is None

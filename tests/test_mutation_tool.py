"""``tools/mutation.py``'s own bookkeeping (docs/testing.md, "Mutation testing"): an
``EQUIVALENT`` entry that names no mutant of its module any more is reported, so that a reason
checked against code that has since moved is checked again rather than kept."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _mutation() -> ModuleType:
    spec = importlib.util.spec_from_file_location("mutation", ROOT / "tools" / "mutation.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["mutation"] = module
    spec.loader.exec_module(module)
    return module


def test_an_equivalent_entry_that_names_no_mutant_of_its_module_is_stale(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The keys of the module run that mutmut made no mutant of are stale; the keys it did
    make a mutant of, and the keys of other modules (not run), even of one whose name starts
    with the module's, are not."""
    tool = _mutation()
    monkeypatch.setattr(tool, "EQUIVALENT", dict.fromkeys((
        "wmr.apps.batch.journal.x_logged_record__mutmut_13",  # made: kept
        "wmr.apps.batch.journal.x_logged_record__mutmut_58",  # the function is shorter now
        "wmr.apps.batch.journal.xǁJournalǁappend__mutmut_31",  # the method is another now
        "wmr.apps.batch.journal_x.x_f__mutmut_1",  # another module
        "wmr.apps.batch.runner.x__verified__mutmut_15"), "why"))
    made = ["wmr.apps.batch.journal.x_logged_record__mutmut_13",
            "wmr.apps.batch.journal.xǁJournalǁappend__mutmut_1"]
    assert tool.stale_equivalents("apps/batch/journal.py", made) == [
        "wmr.apps.batch.journal.x_logged_record__mutmut_58",
        "wmr.apps.batch.journal.xǁJournalǁappend__mutmut_31"]
    assert tool.stale_equivalents("apps/batch/runner.py",
                                  ["wmr.apps.batch.runner.x__verified__mutmut_15"]) == []


def test_every_equivalent_entry_names_a_module_under_mutation() -> None:
    """A key is ``wmr.<module>.<mutant>`` of a module some target mutates: any other would
    never be run, so never found stale either."""
    tool = _mutation()
    modules = {"wmr." + t.source.removesuffix(".py").replace("/", ".") + "."
               for t in tool.TARGETS.values()}
    assert [k for k in tool.EQUIVALENT if not any(k.startswith(m) for m in modules)] == []


def test_every_function_with_equivalent_mutants_is_the_code_they_were_checked_on() -> None:
    """mutmut numbers a function's mutants in the order of its code: once the function is
    edited, an entry's number can name another mutant (the compact journal made the resume's
    ``_verified`` 38 'and' for 'or' in the test of a seal, which an entry called equivalent).
    Each function that has ``EQUIVALENT`` entries is the code it was when they were checked
    (``CHECKED_CODE``), and the module still defines it."""
    tool = _mutation()
    now = tool.checked_code_now()
    changed = sorted(p for p, h in now.items() if h is None or tool.CHECKED_CODE.get(p) != h)
    assert changed == [], (
        f"changed since their equivalent mutants were checked: {changed}: run their mutants "
        "again (tools/mutation.py MODULE --mutants 'PREFIX__mutmut_*'), check each EQUIVALENT "
        "entry against its mutant (mutmut show NAME), then python tools/mutation.py "
        "--code-hashes")
    assert sorted(tool.CHECKED_CODE) == sorted(now), "CHECKED_CODE lists other functions"


MODULE = """
def f(x):
    return x + 1


class C:
    def f(self, x):
        return x - 1
"""


def test_the_code_hash_is_of_the_function_mutmut_names_and_not_of_its_layout() -> None:
    """``x_f`` is the module's function, ``xǁCǁf`` the method of ``C``; comments and line
    breaks, which change no mutant, leave the hash as it is; a changed operator does not."""
    tool = _mutation()
    function, method = tool.code_hash(MODULE, "x_f"), tool.code_hash(MODULE, "xǁCǁf")
    assert function is not None and method is not None and function != method
    assert tool.code_hash(MODULE, "x_g") is None and tool.code_hash(MODULE, "xǁDǁf") is None
    laid_out = MODULE.replace("return x + 1", "# one more\n    return (x\n            + 1)")
    assert tool.code_hash(laid_out, "x_f") == function
    assert tool.code_hash(laid_out, "xǁCǁf") == method
    edited = MODULE.replace("x - 1", "x + 1")
    assert tool.code_hash(edited, "x_f") == function
    assert tool.code_hash(edited, "xǁCǁf") != method

"""Mutation testing of the modules that carry the promises (docs/testing.md).

Each module is mutated by mutmut 3 against only the test modules that cover it, in a scratch
copy of the project (``--work``, default ``$TMPDIR/wmr-mutation``), one module at a time: the
worktree is never changed.  mutmut forks one process per mutant from a warmed-up pytest and
runs only the tests that reach the mutated function, so a mutant costs milliseconds to
seconds rather than a fresh interpreter.

Usage::

    python tools/mutation.py                 # every module (long: see docs/testing.md)
    python tools/mutation.py physics energy  # some of them
    python tools/mutation.py --sample        # the small fixed sample that CI runs
    python tools/mutation.py physics --mutants 'wmr.core.physics.x_outputs__mutmut_*'
    python tools/mutation.py physics --timeout-multiplier 60 --mutants NAME  # confirm a timeout
    python tools/mutation.py --list          # the modules, their tests and functions

Prints a table (module, mutants, killed, survived, equivalent, no tests, timeout) and the
surviving mutants not known to be equivalent; exits 1 when any is left, when an
:data:`EQUIVALENT` key of a module run names none of its mutants any more (stale: the code it
was checked against moved), or, with ``--min-score``, when a module's score is below it.  A
survivor is either killed by a new test or explained in :data:`EQUIVALENT` (and in
docs/testing.md).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Target:
    """One module under mutation and the tests that must kill its mutants."""

    source: str  # under pipelines/wmr
    tests: tuple[str, ...]  # test modules (or node ids) that cover it
    #: fnmatch patterns of mutant names for ``--sample`` (empty: not in the sample)
    sample: tuple[str, ...] = ()
    #: extra pytest arguments (e.g. a -k selection)
    pytest_args: tuple[str, ...] = ()
    #: fnmatch patterns of the mutants to run (empty: every function of the module); for the
    #: large modules whose promise lives in a few functions
    functions: tuple[str, ...] = ()
    #: mutmut stops a mutant's tests after (their unmutated time + 1 s) times this (its default
    #: 15), and counts it killed (a timeout): raised where a surviving mutant's whole test run
    #: (fixtures included, which the estimate leaves out) takes longer on a loaded machine
    timeout_multiplier: float = 15.0


#: The modules that carry the physics, the control law, the energy and effort integrals, the
#: MCAP reader's integrity checks, the batch journal and resume, the archive checks and the
#: build digest (issue 23), each with the one or two test modules that cover it.
TARGETS: dict[str, Target] = {
    "physics": Target("core/physics.py", ("tests/test_physics.py", "tests/test_promises_core.py")),
    "stabiliser": Target("core/control/stabiliser.py",
                         ("tests/test_stabiliser.py", "tests/test_promises_core.py")),
    "actuator": Target("core/control/actuator.py", ("tests/test_actuator.py",),
                       sample=("wmr.core.control.actuator.*",)),
    "energy": Target("core/energy.py", ("tests/test_energy.py::test_the_integrals_of_a_known_power",
                                        "tests/test_promises_core.py"),
                     sample=("wmr.core.energy.x_step_work__mutmut_*",)),
    "ocp_result": Target("adapters/ocp/result.py", ("tests/test_optimal.py",),
                         pytest_args=("-m", "not slow")),
    # the integrity checks: the CRCs, the chunks and the read budget (the record walk and
    # _parse_record, 235 mutants more, are left out for time: docs/testing.md); and the
    # batch's test of a finished log on resume and its result record (log_finished,
    # finished_result: a log wrongly taken as finished is a run never run again), which
    # test_journal covers (through journal.log_complete and logged_record)
    "mcap_reader": Target("adapters/mcap/reader.py",
                          ("tests/test_log_integrity.py", "tests/test_journal.py"),
                          pytest_args=("-m", "not slow"),
                          functions=tuple(f"wmr.adapters.mcap.reader.{f}__mutmut_*" for f in (
                              "x__check_crc", "x__read_chunk", "x__chunk_messages",
                              "xǁLogScanǁdamage", "xǁLogScanǁcharge", "x_log_finished",
                              "x_finished_result"))),
    "batch_journal": Target("apps/batch/journal.py",
                            ("tests/test_journal.py", "tests/test_batch.py"),
                            pytest_args=("-m", "not slow", "-k", "resume or journal or cut"),
                            timeout_multiplier=60.0),  # its tests start batches too
    "batch_resume": Target("apps/batch/runner.py",
                           ("tests/test_promises_batch.py", "tests/test_batch.py"),
                           # (the 9-byte ledger's 22 s memory test left out: every surviving
                           # mutant would wait for it)
                           pytest_args=("-m", "not slow", "-k",
                                        "(resume or cut or stamped or killed or edit or "
                                        "read_back) and not 9_bytes"),
                           # each test starts batches (fixtures of 20 runs): at 15, survivors
                           # such as tqdm(file=None) timed out under load, counted as killed
                           timeout_multiplier=60.0,
                           functions=("wmr.apps.batch.runner.x__verified__mutmut_*",
                                      "wmr.apps.batch.runner.x__resume__mutmut_*",
                                      "wmr.apps.batch.runner.x__recover_partial__mutmut_*")),
    "archive": Target("adapters/fmi/archive.py",
                      ("tests/test_hostile_archives.py", "tests/test_fmu_build.py"),
                      pytest_args=("-k", "hostile or refuse or door or libcosim"),
                      # the refusals of gap 9: member kinds (symlinks), the member count and
                      # sizes, the inflated bytes (zip bombs); names and XML: docs/testing.md
                      functions=tuple(f"wmr.adapters.fmi.archive.{f}__mutmut_*" for f in (
                          "x__check_kind", "xǁCheckedArchiveǁ__init__",
                          "xǁCheckedArchiveǁchunks"))),
    "build_digest": Target("build/fmus.py",
                           ("tests/test_promises_build.py", "tests/test_fmu_build.py"),
                           pytest_args=("-k", "rebuil"),
                           functions=("wmr.build.fmus.x_build_digest__mutmut_*",
                                      "wmr.build.fmus.x__reusable__mutmut_*")),
}

#: Appended to the scratch copy's tests/conftest.py: the session's build folder is one folder
#: in ``--work``, so the FMUs are built once and reused by every mutant's tests (each mutant's
#: pytest session would otherwise build them into its own temporary folder, a minute each);
#: ``fmu_dir`` itself is replaced so that the tests that build into it (the rebuild tests of
#: the build digest) and ``built`` agree on the folder.
_CONFTEST_FMUS = """

@pytest.fixture(scope="session", autouse=True)
def fmu_dir() -> Iterator[Path]:  # noqa: F811 - tools/mutation.py: one build for every mutant
    os.environ["WMR_CACHE_DIR"] = os.environ["WMR_MUTATION_FMU_DIR"]
    yield paths.default_fmu_dir()


@pytest.fixture(scope="session", autouse=True)
def _own_forkserver() -> None:
    # mutmut forks each mutant's pytest from the process that ran the unmutated tests, whose
    # multiprocessing forkserver (started by the batch runner) is not the fork's child: the
    # batch's next worker then fails with ECHILD and every mutant counts as killed.  Forget
    # it, so that each mutant's session starts its own.
    import multiprocessing.forkserver

    multiprocessing.forkserver._forkserver.__init__()
"""

_STAB = "wmr.core.control.stabiliser.xǁPointStabiliserǁ"
_SERVO = "wmr.core.control.actuator.xǁWheelServoǁ"
_ZERO_ERROR = "the error is exactly 0 there, so the integral adds k * 0 * h = 0 either way"
_AT_THE_LIMIT = ("u exactly on the limit (a set of measure zero): u_s is the limit either way; "
                 "the original integrates that one step, the mutant freezes it, both keep the "
                 "integral bounded; the C controller (fmu/src/controller) has the original's "
                 "comparison and the two agree bit for bit")

#: Surviving mutants that are equivalent (no test can tell them from the original), with why.
#: Keys are mutmut's mutant names.
EQUIVALENT: dict[str, str] = {
    # core/physics.py
    "wmr.core.physics.x_outputs__mutmut_11": "dtype=None: numpy makes float64 of these floats",
    "wmr.core.physics.x_outputs__mutmut_13": "dtype dropped: numpy makes float64 of these floats",
    **{f"wmr.core.physics.xǁReferencePlantǁreset__mutmut_{n}": (
        "dtype dropped: the list holds the literals 0.0, numpy makes float64 of it")
       for n in (8, 10)},
    "wmr.core.physics.xǁReferencePlantǁstep__mutmut_28": (
        "DOP853 dropped: RK45 at the same tolerances is as accurate (only slower)"),
    "wmr.core.physics.xǁReferencePlantǁstep__mutmut_35": (
        "the message of a solve_ivp failure, which this smooth ODE never reaches with finite "
        "torques (tried: Coulomb friction of 1e6 N m over 1e-6 rad/s)"),
    # core/control/stabiliser.py
    f"{_STAB}__init____mutmut_14": "self.r is stored but never read (update uses inv_r)",
    f"{_STAB}update__mutmut_40": "beta exactly +beta_max: the clamp returns beta_max = beta",
    f"{_STAB}update__mutmut_42": "beta exactly -beta_max: the clamp returns -beta_max = beta",
    f"{_STAB}update__mutmut_99": _AT_THE_LIMIT,
    f"{_STAB}update__mutmut_107": _AT_THE_LIMIT,
    f"{_STAB}update__mutmut_126": _AT_THE_LIMIT,
    f"{_STAB}update__mutmut_134": _AT_THE_LIMIT,
    f"{_STAB}update__mutmut_101": _ZERO_ERROR,
    f"{_STAB}update__mutmut_109": _ZERO_ERROR,
    f"{_STAB}update__mutmut_128": _ZERO_ERROR,
    f"{_STAB}update__mutmut_138": _ZERO_ERROR,
    f"{_STAB}update__mutmut_164": "|w_l| == |w_r|: either is the peak",
    f"{_STAB}update__mutmut_165": (
        "peak exactly wheel_max scaled too: k = wheel_max / peak = 1.0 exactly, the speeds "
        "unchanged (wheel_max > 0 and finite: Limits is checked)"),
    # adapters/ocp/result.py: the rollout's RK4 made finer still, and the first node's input
    **{f"wmr.adapters.ocp.result.x__dense__mutmut_{n}": (
        "more RK4 sub-steps in each fine step: a result closer to the exact one by less than "
        "the RK4 error (about 1e-12 m), which no documented figure can tell") for n in (14, 16)},
    **{f"wmr.adapters.ocp.result.x__dense__mutmut_{n}": (
        "the input paired with the first node: no output depends on the torques (no direct "
        "feedthrough, tests/test_fmu_model_structure.py), and a solved NLP always has "
        "torques") for n in (23, 24, 25, 26, 27)},
    **{f"wmr.adapters.ocp.result.x__dense__mutmut_{n}": (
        "dtype=float dropped: an integer arange times a float, and CasADi's DM, are float64 "
        "anyway") for n in (64, 66, 70, 72)},
    "wmr.adapters.ocp.result.x__integrals__mutmut_26": (
        "/ for //: (len(t) - 1) is a multiple of the interval count, the quotient 10.0 "
        "repeats as 10"),
    "wmr.adapters.ocp.result.x__integrals__mutmut_33": (
        "max(n, 2) for max(n, 1): the OCP has at least 2 intervals (n_intervals >= 2)"),
    # core/control/actuator.py
    f"{_SERVO}update__mutmut_20": "v exactly +t_max: the saturation returns t_max = v",
    f"{_SERVO}update__mutmut_24": "v exactly -t_max: the saturation returns -t_max = v",
    # adapters/mcap/reader.py
    "wmr.adapters.mcap.reader.x__read_chunk__mutmut_25": (
        "unpack_from(body, 0) with the offset dropped: 0 is its default"),
    **{f"wmr.adapters.mcap.reader.x__read_chunk__mutmut_{n}": (
        "every chunk walked record by record (_chunk_messages; spans = None, or 'or True'): it "
        "finds exactly the records the numpy walk finds when every record is a Message "
        "(test_log_integrity's look-alike headers test), only slower, which benchmarks/ "
        "measure") for n in (46, 50)},
    **{f"wmr.adapters.mcap.reader.x__chunk_messages__mutmut_{n}": (
        "np.int64 dropped from np.array of a list of Python ints: numpy 2 (pyproject: "
        "numpy>=2.0) makes int64 of them on every platform; an empty list (float64) is never "
        "used as an index: add_messages returns first when heads is empty")
       for n in (43, 45, 47, 49)},
    "wmr.adapters.mcap.reader.x_finished_result__mutmut_19": (
        "next() without its default None: the StopIteration is an Exception, caught: None"),
    # build/fmus.py: the digest's separators and the label of a host build (its value changes,
    # not what goes into it)
    **{f"wmr.build.fmus.x_build_digest__mutmut_{n}": (
        "another separator between the versions or the platforms ('XX XX' for ' '): every "
        "input still enters the digest, which is compared only with itself") for n in (29, 32)},
    **{f"wmr.build.fmus.x_build_digest__mutmut_{n}": (
        "another label for a host compiler's platforms ('XXhostXX', 'HOST' for 'host'): a "
        "constant, so the digest still changes exactly when an input does") for n in (35, 36)},
    # apps/batch/journal.py
    "wmr.apps.batch.journal.xǁJournalǁ__init____mutmut_2": (
        "_checked = None for False: only ever tested as 'not self._checked', both falsy"),
    **{f"wmr.apps.batch.journal.x_logged_record__mutmut_{n}": (
        "another default for a missing message (None, 'XXXX'): it is only tested for starting "
        "with 'WallClockLimit', which none of them does") for n in (13, 15, 18)},
    "wmr.apps.batch.journal.x_logged_record__mutmut_36": (
        "rpartition for partition of 'WallClockLimit: <text>': the text is "
        "worker.wall_limit_message's ('wall-clock limit of {limit_s:g} s exceeded'), which "
        "holds no ': '"),
    **{f"wmr.apps.batch.journal.xǁJournalǁ_ends_with_newline__mutmut_{n}": (
        "read(None) or read(2) for read(1) after seeking to the last byte: one byte is left "
        "either way") for n in (13, 14)},
    **{f"wmr.apps.batch.journal.xǁJournalǁappend_lines__mutmut_{n}": (
        "_checked = None or False for True once mended: every open of the journal (its first "
        "append, or the next after a close) then reads its last byte, which is the newline "
        "this journal wrote (the batch folder's lock makes it the only writer): the same "
        "bytes, one 1-byte read more an open")
       for n in (28, 29)},
    **{f"wmr.apps.batch.journal.xǁJournalǁ__init____mutmut_{n}": (
        "_size = None or 1 for 0: it is set from the file's size when the journal is opened, "
        "before anything reads it") for n in (5, 6)},
    "wmr.apps.batch.journal.x_row_bytes__mutmut_3": (
        "allow_nan=None for False: json only tests it for truth, NaN still raises ValueError"),
    **{f"wmr.apps.batch.journal.x_row_bytes__mutmut_{n}": (
        "allow_nan dropped or True: a worker's row holds no NaN (summary._float makes a "
        "non-finite value None), so no seal was made over one; a row read back with a NaN "
        "(edited) is other bytes ('NaN' for 'null'), and its CRC, as any edited row's, "
        "misses the seal: the run is redone either way (the resume takes the ValueError as "
        "'not sealed')") for n in (7, 10)},
    **{f"wmr.apps.batch.journal.x_sealed_line__mutmut_{n}": (
        "sealed_line's allow_nan=False as None, dropped or True: line_check(row) just before "
        "already raises ValueError on a NaN (allow_nan=False), the only value it would "
        "refuse, and the seal it adds is a hex string") for n in (7, 10, 12)},
    "wmr.apps.batch.journal.x_line_check__mutmut_8": (
        "allow_nan=None for False: json only tests it for truth, NaN still raises ValueError"),
    "wmr.apps.batch.journal.xǁJournalǁscan__mutmut_12": (
        "readline(MAX_LINE_BYTES + 2) for + 1 in scan: a line of at most MAX_LINE_BYTES is "
        "read whole either way, a longer one is skipped to its newline either way (the offsets "
        "count the bytes read)"),
    "wmr.apps.batch.journal.xǁJournalǁread_at__mutmut_23": (
        "readline(MAX_LINE_BYTES + 2) for + 1: a line of at most MAX_LINE_BYTES is read whole "
        "either way, a longer one is read one byte further and refused by _parse's own bound"),
    # apps/batch/runner.py
    **{f"wmr.apps.batch.runner.x__resume__mutmut_{n}": (
        "the journal check's bar given file=None or no file: tqdm then writes to sys.stderr, "
        "as asked") for n in (10, 17)},
    # (_verified's 15 entries were removed: the compact journal (issue 31) rewrote _verified,
    # and their numbers named other mutants since, such as 38, 'and' made 'or' in the test of
    # a line's seal; its mutants are to be run again: docs/testing.md)
    **{f"wmr.apps.batch.runner.x__recover_partial__mutmut_{n}": (
        "another name for the scratch file the partial log is moved to (.KILLED, "
        "XX.killedXX): any name but the recovered log's own .partial works alike, and none "
        "is documented") for n in (6, 7)},
}

#: The code of each function that has equivalent mutants, as it was when they were checked:
#: :func:`code_hash` of the function, by its mutants' prefix.  mutmut numbers a function's
#: mutants in the order of its code, so an edit of the function can give an entry's number to
#: another mutant; tests/test_mutation_tool.py fails until the function's mutants are run
#: again, the entries checked against them (``mutmut show NAME`` in the scratch folder), and
#: the hash written here (``--code-hashes`` prints them).
CHECKED_CODE: dict[str, str] = {
    "wmr.adapters.mcap.reader.x__chunk_messages": "e4039932cd94",
    "wmr.adapters.mcap.reader.x__read_chunk": "75dc94e4dbcd",
    "wmr.adapters.mcap.reader.x_finished_result": "4c5378d4b986",
    "wmr.adapters.ocp.result.x__dense": "e8147eed7675",
    "wmr.adapters.ocp.result.x__integrals": "78b652a3f0bf",
    "wmr.apps.batch.journal.x_line_check": "6733695feb5d",
    "wmr.apps.batch.journal.x_logged_record": "fc979d524b89",
    "wmr.apps.batch.journal.x_row_bytes": "eb6f7a32f560",
    "wmr.apps.batch.journal.x_sealed_line": "d65f94d9c966",
    "wmr.apps.batch.journal.xǁJournalǁ__init__": "31c1fd20ce66",
    "wmr.apps.batch.journal.xǁJournalǁ_ends_with_newline": "b8bf172ec9d3",
    "wmr.apps.batch.journal.xǁJournalǁappend_lines": "3fd97e4ffb85",
    "wmr.apps.batch.journal.xǁJournalǁread_at": "74dddb57e5dd",
    "wmr.apps.batch.journal.xǁJournalǁscan": "eff48e39103c",
    "wmr.apps.batch.runner.x__recover_partial": "ea48e6f88794",
    "wmr.apps.batch.runner.x__resume": "c72a55d80584",
    "wmr.build.fmus.x_build_digest": "a2c75e72796f",
    "wmr.core.control.actuator.xǁWheelServoǁupdate": "c107b9ef5763",
    "wmr.core.control.stabiliser.xǁPointStabiliserǁ__init__": "34ee82caad38",
    "wmr.core.control.stabiliser.xǁPointStabiliserǁupdate": "a27024ce6785",
    "wmr.core.physics.x_outputs": "d119984f9fe3",
    "wmr.core.physics.xǁReferencePlantǁreset": "88eb5a2c6013",
    "wmr.core.physics.xǁReferencePlantǁstep": "f34f89978f0a",
}

#: mutmut's exit codes of a mutant's test run, as its own ``status_by_exit_code`` reads them.
_KILLED = {1, 3, -9, -11, 37}
_SURVIVED = {0}
_NO_TESTS = {5, 33}
_TIMEOUT = {24, -24, 36, 152, 255}


def _scratch(work: Path, name: str, target: Target) -> Path:
    """A copy of the project laid out as mutmut expects (``src/wmr``), for one target."""
    root = work / name
    if root.exists():
        shutil.rmtree(root)
    root.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".mypy_cache")
    shutil.copytree(ROOT / "pipelines" / "wmr", root / "src" / "wmr", ignore=ignore)
    shutil.copytree(ROOT / "tests", root / "tests", ignore=ignore)
    with open(root / "tests" / "conftest.py", "a") as conftest:
        conftest.write(_CONFTEST_FMUS)
    also = ["modelica", "fmu", "scenarios", "LICENSE"]
    for item in also:
        src = ROOT / item
        if src.is_dir():
            shutil.copytree(src, root / item, ignore=ignore)
        elif src.exists():
            shutil.copy2(src, root / item)
    pytest_args = ["-p", "no:xdist", "-p", "no:cacheprovider", "-q", "-x",
                   *target.pytest_args]
    (root / "pyproject.toml").write_text(
        "[tool.pytest.ini_options]\n"
        'testpaths = ["tests"]\n'
        'addopts = "--strict-markers"\n'
        "timeout = 900\n"
        'markers = ["slow: long runs"]\n\n'
        "[tool.mutmut]\n"
        'source_paths = ["src"]\n'
        f'only_mutate = ["src/wmr/{target.source}"]\n'
        f"also_copy = {json.dumps(also)}\n"
        f"pytest_add_cli_args = {json.dumps(pytest_args)}\n"
        f"pytest_add_cli_args_test_selection = {json.dumps(list(target.tests))}\n"
        f"timeout_multiplier = {target.timeout_multiplier}\n"
        "use_git_change_detection = false\n")
    return root


@dataclass
class Score:
    name: str
    mutants: int = 0
    killed: int = 0
    survived: int = 0
    equivalent: int = 0
    no_tests: int = 0
    timeout: int = 0
    other: int = 0
    wall_s: float = 0.0

    @property
    def percent(self) -> float:
        """Killed over the mutants that are not equivalent, %."""
        n = self.mutants - self.equivalent
        return 100.0 * self.killed / n if n else 100.0


def stale_equivalents(source: str, mutant_names: Iterable[str]) -> list[str]:
    """The :data:`EQUIVALENT` keys of the module ``source`` (under pipelines/wmr) that name
    none of its mutants ``mutant_names`` (every mutant mutmut made of it, run or not): the
    function they meant was moved, renamed or removed, so their reason was never checked
    against the code there now."""
    prefix = "wmr." + source.removesuffix(".py").replace("/", ".") + "."
    names = set(mutant_names)
    return sorted(k for k in EQUIVALENT if k.startswith(prefix) and k not in names)


def _function(text: str, mangled: str) -> ast.FunctionDef | ast.AsyncFunctionDef | None:
    """The function of the module ``text`` that mutmut names ``mangled`` (``x_name``, or
    ``xǁClassǁname`` for a method), ``None`` if it has none."""
    if mangled.startswith("xǁ"):
        _, cls, name = mangled.split("ǁ")
    else:
        cls, name = "", mangled.removeprefix("x_")
    body: list[ast.stmt] = ast.parse(text).body
    if cls:
        body = next((n.body for n in body if isinstance(n, ast.ClassDef) and n.name == cls), [])
    return next((n for n in body if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
                 and n.name == name), None)


def code_hash(text: str, mangled: str) -> str | None:
    """A hash of the code of the function mutmut names ``mangled`` in the module ``text`` (12
    hex digits of the SHA-256 of ``ast.unparse``: comments and layout, which change no mutant,
    left out), ``None`` if the module has no such function."""
    node = _function(text, mangled)
    if node is None:
        return None
    return hashlib.sha256(ast.unparse(node).encode()).hexdigest()[:12]


def checked_code_now() -> dict[str, str | None]:
    """:data:`CHECKED_CODE` as the code is now: the :func:`code_hash` of each function that
    has :data:`EQUIVALENT` entries, by their prefix (``wmr.<module>.<mangled name>``)."""
    modules = {"wmr." + t.source.removesuffix(".py").replace("/", "."): t.source
               for t in TARGETS.values()}
    texts: dict[str, str] = {}
    hashes: dict[str, str | None] = {}
    for key in EQUIVALENT:
        prefix = key.partition("__mutmut_")[0]
        module, _, mangled = prefix.rpartition(".")
        if module in modules and prefix not in hashes:
            if module not in texts:
                texts[module] = (ROOT / "pipelines" / "wmr" / modules[module]).read_text()
            hashes[prefix] = code_hash(texts[module], mangled)
    return hashes


def _results(root: Path, name: str, target: Target) -> tuple[Score, list[str], list[str]]:
    meta = root / "mutants" / "src" / "wmr" / (target.source + ".meta")
    data = json.loads(meta.read_text())
    score, survivors = Score(name), []
    stale = stale_equivalents(target.source, data.get("exit_code_by_key", {}))
    for mutant, code in sorted(data.get("exit_code_by_key", {}).items()):
        if code is None:  # not run (outside the sample)
            continue
        score.mutants += 1
        if code in _KILLED:
            score.killed += 1
        elif code in _SURVIVED or code in _NO_TESTS:
            if mutant in EQUIVALENT:
                score.equivalent += 1
                continue
            if code in _NO_TESTS:
                score.no_tests += 1
            else:
                score.survived += 1
            survivors.append(mutant)
        elif code in _TIMEOUT:
            score.timeout += 1  # an endless loop the tests stopped: counted as killed below
            score.killed += 1
        else:
            score.other += 1
            survivors.append(f"{mutant} (exit code {code})")
    return score, survivors, stale


def run_target(name: str, target: Target, work: Path, sample: bool,
               max_children: int, mutants: tuple[str, ...] = ()
               ) -> tuple[Score, list[str], list[str]]:
    root = _scratch(work, name, target)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MUTANT_UNDER_TEST")}
    env["MPLBACKEND"] = "Agg"
    env["WMR_MUTATION_FMU_DIR"] = str(work / "fmus")
    cmd = [sys.executable, "-c", "from mutmut.__main__ import cli; cli()", "run",
           "--max-children", str(max_children)]
    if mutants:
        cmd += list(mutants)
    elif sample:
        cmd += list(target.sample)
    else:
        cmd += list(target.functions)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    (work / f"{name}.log").write_text(proc.stdout + proc.stderr)
    # mutmut 3 exits 0 when its first, unmutated test run fails ("failed to collect stats"),
    # having run no mutant: that is a failure here, never a score of 100 %
    if proc.returncode not in (0, 1) or not (root / "mutants").exists() \
            or "failed to collect stats" in proc.stdout + proc.stderr:
        raise SystemExit(f"mutmut failed on {name} (exit {proc.returncode}); see "
                         f"{work / (name + '.log')}:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    score, survivors, stale = _results(root, name, target)
    score.wall_s = wall
    return score, survivors, stale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("modules", nargs="*", help=f"of {', '.join(TARGETS)} (default: all)")
    parser.add_argument("--sample", action="store_true",
                        help="only the fixed sample of mutants (what CI runs)")
    parser.add_argument("--work", type=Path,
                        default=Path(tempfile.gettempdir()) / "wmr-mutation",
                        help="scratch folder (default: %(default)s)")
    parser.add_argument("--max-children", type=int, default=1,
                        help="mutants tested at once (default 1: a shared 2-core machine)")
    parser.add_argument("--min-score", type=float, default=None,
                        help="fail when a module scores below this %%")
    parser.add_argument("--mutants", nargs="+", default=(), metavar="PATTERN",
                        help="only the mutants whose names match these fnmatch patterns "
                             "(e.g. the survivors of a previous run, to see them killed)")
    parser.add_argument("--timeout-multiplier", type=float, default=None, metavar="X",
                        help="mutmut's timeout multiplier for this run (default: the "
                             "target's); higher, to confirm that the timeouts of a run loop")
    parser.add_argument("--list", action="store_true", help="list the modules and exit")
    parser.add_argument("--code-hashes", action="store_true",
                        help="print CHECKED_CODE as the code is now (for the functions whose "
                             "equivalent mutants were checked again) and exit")
    args = parser.parse_args(argv)
    if args.code_hashes:
        for prefix, digest in sorted(checked_code_now().items()):
            print(f'    "{prefix}": "{digest}",')
        return 0
    if args.list:
        for name, t in TARGETS.items():
            print(f"{name:14} wmr/{t.source:30} {' '.join(t.tests)}")
        return 0
    unknown = [m for m in args.modules if m not in TARGETS]
    if unknown:
        parser.error(f"unknown module(s) {', '.join(unknown)}; give some of {', '.join(TARGETS)}")
    names = args.modules or list(TARGETS)
    if args.sample:
        names = [n for n in names if TARGETS[n].sample]
    rows: list[Score] = []
    left: list[str] = []
    stale: list[str] = []
    for name in names:
        target = TARGETS[name]
        if args.timeout_multiplier is not None:
            target = dataclasses.replace(target, timeout_multiplier=args.timeout_multiplier)
        score, survivors, stale_keys = run_target(name, target, args.work, args.sample,
                                                  args.max_children, tuple(args.mutants))
        rows.append(score)
        left += survivors
        stale += stale_keys
    print("| module | mutants | killed | survived | equivalent | no tests | timeout | score | "
          "wall s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for s in rows:
        print(f"| {s.name} | {s.mutants} | {s.killed} | {s.survived} | {s.equivalent} | "
              f"{s.no_tests} | {s.timeout} | {s.percent:.1f} % | {s.wall_s:.0f} |")
    for mutant in left:
        print(f"survived: {mutant}")
    for key in stale:
        print(f"stale: EQUIVALENT names {key}, which is no mutant of its module any more "
              "(its code moved or changed): remove it, and run the module again")
    low = [s.name for s in rows if args.min_score is not None and s.percent < args.min_score]
    if low:
        print(f"below {args.min_score} %: {', '.join(low)}")
    return 1 if left or low or stale else 0


if __name__ == "__main__":
    sys.exit(main())

"""The ``wmr`` command line.  Every failure ends as one line on stderr and a non-zero exit."""

from __future__ import annotations

import argparse
import errno
import json
import re
import signal
import sys
import time
from collections.abc import Callable, Sequence
from contextvars import ContextVar
from types import FrameType
from typing import Any

from wmr import __version__
from wmr.infra.errors import ConfigError, DiskFullError, WmrError

Handler = Callable[[argparse.Namespace], int]
#: ``supervisor(args, run)``: runs ``run(notify)`` (the command, ``notify`` told of the first
#: stop signal) its own way and returns the exit status (``wmr run``: in a watched child).
Supervisor = Callable[[argparse.Namespace, Callable[[Callable[[int], None] | None], int]], int]

#: Longest field name (``--param`` key, TOML key, an input's path, ...) an error line echoes:
#: a field is often a path, and at 80 the middle of an ordinary one was left out (CI's
#: temporary folders); a hostile key is still cut, and the whole line at MAX_LINE_CHARS.
MAX_FIELD_CHARS = 300
#: Longest error line; a longer one keeps its start and its end (the fix) around an ellipsis.
MAX_LINE_CHARS = 600
# C0 and C1 controls, DEL, line and paragraph separators, and the bidirectional overrides and
# isolates (which reorder what a terminal shows): never written raw to a terminal
_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")


def _cut(text: str, limit: int) -> str:
    """``text`` whole, or its start and end around an ellipsis saying how long it was."""
    if len(text) <= limit:
        return text
    note = f"... ({len(text)} characters) ..."
    head = (limit - len(note)) * 2 // 3
    return f"{text[:head]}{note}{text[len(text) - (limit - len(note) - head):]}"


def error_line(exc: BaseException) -> str:
    """The one line that reports ``exc``: its first line, the field of a
    :class:`~wmr.infra.errors.ConfigError` cut to :data:`MAX_FIELD_CHARS`, control and
    reordering characters escaped (``\\x1b``), the whole cut to :data:`MAX_LINE_CHARS`.

    The one place where text a user (or a hostile file) gave reaches the terminal in an error.
    """
    if isinstance(exc, ConfigError):
        text = f"{_cut(exc.field, MAX_FIELD_CHARS)}: {exc.problem}"
        if exc.fix:
            text += f" ({exc.fix})"
    else:
        text = str(exc)
    lines = text.splitlines() or [type(exc).__name__]
    more = " (run with --debug for details)" if len(lines) > 1 else ""
    line = _UNPRINTABLE.sub(lambda m: ascii(m.group())[1:-1], lines[0])
    return _cut(line, MAX_LINE_CHARS) + more


#: Address space (``ulimit -v``) below which wmr cannot load its modules: numpy, pyarrow and
#: CasADi map their libraries and OpenBLAS its buffers (``wmr --version`` needs about 190 MB on
#: x86_64 Linux; below about 120 MB OpenBLAS ends the process itself, uncatchably).
MIN_ADDRESS_SPACE_BYTES = 160 * 2**20
_LOADING = " loading wmr's modules"
# what the dynamic loader says when mmap fails for lack of address space
_NO_MAP = re.compile(r"failed to map segment|cannot allocate memory", re.IGNORECASE)


def _address_space_limit() -> int | None:
    """The soft ``ulimit -v`` in bytes; ``None`` when there is none (or no such limit)."""
    try:
        import resource
    except ImportError:  # not POSIX
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    return None if soft == resource.RLIM_INFINITY else soft


def out_of_memory(what: str = "") -> str:
    """The one line of a command that ran out of memory ``what`` (`` loading wmr's modules``),
    naming the ``ulimit -v`` if any (a limit per process: fewer workers would not help)."""
    limit = _address_space_limit()
    if limit is None:
        return f"out of memory{what}: give the process more memory, or run fewer --workers"
    return (f"out of memory{what} (ulimit -v is {limit // 1024} kB): raise ulimit -v (e.g. "
            f"ulimit -v {max(4 * limit, 4 * MIN_ADDRESS_SPACE_BYTES) // 1024}, or unlimited)")


def _from_memory(exc: BaseException) -> bool:
    """Whether ``exc`` is a lack of memory: a MemoryError (or one that caused it), a shared
    library that could not be mapped (numpy and pyarrow raise ImportError), or a SyntaxError
    from importing under a ``ulimit -v`` (CPython's parser reports a failed allocation so)."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, MemoryError) or (isinstance(seen, ImportError)
                                             and _NO_MAP.search(str(seen))):
            return True
        seen = seen.__cause__ or seen.__context__
    return isinstance(exc, SyntaxError) and _address_space_limit() is not None


def _environment_error(exc: OSError | MemoryError) -> str:
    """An error of the machine, not of wmr (too many open files, no memory, a name too long for
    the file system, a folder removed under it): one line saying which and what to do."""
    if isinstance(exc, MemoryError):
        return out_of_memory()
    what = exc.strerror or type(exc).__name__
    where = f"{exc.filename}: " if exc.filename is not None else ""
    fix = {errno.EMFILE: "raise the limit (ulimit -n) or run fewer --workers",
           errno.ENFILE: "close some programs or run fewer --workers",
           errno.ENOMEM: "give the process more memory, or run fewer --workers",
           errno.ENAMETOOLONG: "give a shorter file name",
           errno.ENOENT: "check that the folder still exists"}.get(exc.errno or 0, "")
    return f"{where}{what}" + (f" ({fix})" if fix else "")


#: Whether the command line being parsed asked for ``--json`` (set by :func:`main`): a parse
#: error of a command that has ``--json`` is then one JSON line (:meth:`_Parser.error`).
_JSON_ASKED: ContextVar[bool] = ContextVar("wmr_cli_json_asked", default=False)


class _Parser(argparse.ArgumentParser):
    """argparse's parser, whose usage errors are one sanitised line (argparse echoes the
    value it could not parse: a 100,000-character or escape-laden one must not reach the
    terminal raw).  Sub-command parsers are made of the same class.

    No option is taken by a prefix of its name (``allow_abbrev=False``): ``--controller``
    must never pass for ``--controller-fmu``, nor a typo for another option.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs["allow_abbrev"] = False
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> Any:  # argparse's signature: NoReturn
        line = error_line(Exception(message))
        if _JSON_ASKED.get() and "--json" in self._option_string_actions:
            # refused input of a command given --json: the README's contract, one JSON line
            # on stdout (as any refused input) and exit 1, the error on stderr
            print(f"{self.prog}: error: {line}", file=sys.stderr)
            record = {"status": "error", "message": line}
            field = re.match(r"argument (\S+?)(?:/\S+)?: ", message)
            if field is not None:
                record["field"] = field.group(1)
            print(json.dumps(record))
            self.exit(1)
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {line}\n")


def _cmd_fmu_build(args: argparse.Namespace) -> int:
    from wmr.build.fmus import summarize
    from wmr.infra.outputs import check_output

    if args.out is not None:
        check_output(args.out, "--out", "dir")
    from wmr.cli.building import build_for

    result = build_for(args, args.out)
    # Standard output stays one path a line (scripts read it); what each FMU offers goes to
    # standard error.
    for fmu in [result.fmus[v] for v in sorted(result.fmus)] + \
            [result.controllers[v] for v in sorted(result.controllers)]:
        print(fmu)
        print(summarize(fmu).line(result.platforms), file=sys.stderr)
    if args.verbose:
        state = "reused" if result.reused else "built"
        print(f"{state}: digest {result.digest[:16]}", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    from wmr.cli import crosscheck
    from wmr.cli.building import add_platforms_option

    parser: argparse.ArgumentParser = _Parser(
        prog="wmr",
        description="Co-simulation and log analysis of a two-wheeled differential-drive robot.")
    parser.add_argument("--version", action="version", version=f"wmr-cosim {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    fmu = sub.add_parser("fmu", help="build the FMUs from the Modelica model")
    fmu_sub = fmu.add_subparsers(dest="fmu_command", metavar="ACTION", required=True)
    build = fmu_sub.add_parser(
        "build", help="build (or reuse, if nothing changed) the robot and controller FMUs",
        description="Build the robot's and the controller's FMI 2.0 and FMI 3.0 FMUs (the robot "
                    "with co-simulation and model exchange) and print their paths, one a line "
                    "(standard error says what each offers: FMI version, interfaces, platforms, "
                    "and each step of a build). With the ziglang package the binaries cover "
                    "x86_64-linux, aarch64-linux, x86_64-windows, x86_64-darwin and "
                    "aarch64-darwin (Zig's first use on a machine builds its C libraries: "
                    "minutes); with gcc, the host only. wmr run builds for the host only, in "
                    "its own cache folder.")
    build.add_argument("--out", metavar="DIR", default=None,
                       help="output folder (default: ~/.cache/wmr-cosim/fmu for all "
                            "platforms, fmu-PLATFORM[+PLATFORM...] beside it for fewer)")
    add_platforms_option(build)
    build.add_argument("--force", action="store_true", help="rebuild even if nothing changed")
    build.add_argument("-v", "--verbose", action="store_true", help="say whether it rebuilt")
    build.set_defaults(handler=_cmd_fmu_build)
    crosscheck.register(fmu_sub)

    for register in _extra_commands():
        register(sub)
    return parser


def _extra_commands() -> list[Callable[[argparse._SubParsersAction[argparse.ArgumentParser]],
                                        None]]:
    """The ``register`` functions of the other sub-commands, in ``--help`` order."""
    from wmr.cli import batch, benchmark, figures, log, optimal, replay, rerun, run, ssp, tune

    return [run.register, replay.register, figures.register, batch.register, rerun.register,
            optimal.register, benchmark.register, tune.register, ssp.register, log.register]


#: Within this time of the first stop signal, the same signal again is the copy a supervising
#: parent forwarded (``wmr run``), s.
_SAME_SIGNAL_S = 0.25


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler, ``timeout``, ``kill``): handled like Ctrl-C, exit status 143."""


class _Signals:
    """SIGINT and SIGTERM stop a command the same way: the first raises in the main thread
    (:class:`KeyboardInterrupt` or :class:`Terminated`), so that logs get their ``failed``
    result and batches their summary; later ones, while that cleanup runs, are only noted
    (a second Ctrl-C must not cut the cleanup short).  The exit status is ``128 + signal``
    of the first (130, 143), as shells report it."""

    def __init__(self, notify: Callable[[int], None] | None = None) -> None:
        self.first: int | None = None
        self._old: dict[int, Any] = {}
        self._notify = notify  # told of the first signal (a supervising parent: wmr run)
        self._at = 0.0  # when the first came (time.monotonic)
        self._held = False  # the first came while a log was being finished

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        from wmr.infra.durable import stop_signal_held

        if self._held:  # the first signal again, delivered once a log was whole
            if stop_signal_held(signum):  # (a second signal while the hold lasts: noted)
                if self._notify is None or signum != self.first or \
                        time.monotonic() - self._at > _SAME_SIGNAL_S:
                    print("wmr: already stopping, finishing the logs and the summary",
                          file=sys.stderr)
                return
            self._held = False
            raise Terminated() if self.first == signal.SIGTERM else KeyboardInterrupt()
        if self.first is not None:
            # a supervising parent forwards the signal that a Ctrl-C also sent this process:
            # the same signal at once is that one, not a second Ctrl-C
            if self._notify is None or signum != self.first or \
                    time.monotonic() - self._at > _SAME_SIGNAL_S:
                print("wmr: already stopping, finishing the logs and the summary",
                      file=sys.stderr)
            return
        self.first, self._at = signum, time.monotonic()
        if self._notify is not None:
            self._notify(signum)
        if stop_signal_held(signum):  # a log is being finished: raised when it is whole
            self._held = True
            return
        raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()

    def install(self) -> None:
        for signum in (signal.SIGINT, signal.SIGTERM):
            try:
                self._old[signum] = signal.signal(signum, self._on_signal)
            except ValueError:  # not the main thread (main() called from a thread)
                return

    def restore(self) -> None:
        """Put the old handlers back, unless a signal came: the process is ending then, and
        a late second signal must not turn into a traceback."""
        if self.first is None:
            for signum, old in self._old.items():
                signal.signal(signum, old)

    def status(self, default: int) -> int:
        return 128 + self.first if self.first is not None else default


def _json_error(args: argparse.Namespace, message: str, exc: BaseException) -> None:
    """With ``--json``, a failure is a JSON line on stdout too, so that a script that reads the
    last line always gets an object (``status`` ``error``, ``field`` for bad input)."""
    if not getattr(args, "json", False):
        return
    # a full disk fails the run; anything else is an error of the command
    status = "failed" if isinstance(exc, DiskFullError) else "error"
    record: dict[str, str] = {"status": status, "message": message.replace("\n", " ")}
    if isinstance(exc, ConfigError):
        record["field"] = exc.field
    print(json.dumps(record))


def main(argv: Sequence[str] | None = None) -> int:
    limit = _address_space_limit()
    if limit is not None and limit < MIN_ADDRESS_SPACE_BYTES:  # fail now, not in an import
        print(f"wmr: error: out of memory: ulimit -v is {limit // 1024} kB, below the "
              f"{MIN_ADDRESS_SPACE_BYTES // 1024} kB that loading wmr's modules needs: raise "
              f"it (e.g. ulimit -v {4 * MIN_ADDRESS_SPACE_BYTES // 1024}, or unlimited)",
              file=sys.stderr)
        return 1
    try:  # the sub-commands' modules (numpy, pyarrow, ...) load here and in the handler
        parser = build_parser()
    except (MemoryError, ImportError, SyntaxError) as exc:
        if not _from_memory(exc) or "--debug" in (sys.argv if argv is None else argv):
            raise
        print(f"wmr: error: {out_of_memory(_LOADING)}", file=sys.stderr)
        return 1
    args = _parse(parser, sys.argv[1:] if argv is None else list(argv))
    handler: Handler = args.handler
    supervisor: Supervisor | None = getattr(args, "supervisor", None)
    if supervisor is not None and argv is None:
        # the process's own command (not main() called by a program or a test, whose
        # output a child would not reach): the command runs in a child it watches
        return supervisor(args, lambda notify: _run_command(handler, args, notify))
    return _run_command(handler, args)


def _run_command(handler: Handler, args: argparse.Namespace,
                 notify: Callable[[int], None] | None = None) -> int:
    """Run the command with SIGINT and SIGTERM handled (:class:`_Signals`; ``notify`` is
    told of the first); its exit status."""
    signals = _Signals(notify)
    signals.install()
    try:
        return signals.status(_dispatch(handler, args))
    except KeyboardInterrupt as exc:  # raised outside the handler's own cleanup
        if signals.first is None:
            signals.first = signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT
        return signals.status(130)
    finally:
        signals.restore()


def _parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """``argv`` parsed; an argument no parser took is refused by the deepest sub-command's
    parser (its usage, and its ``--json`` contract), not by ``wmr``'s."""
    token = _JSON_ASKED.set("--json" in argv)
    try:
        args, extras = parser.parse_known_args(argv)
        if extras:
            _command_parser(parser, args).error(f"unrecognized arguments: {' '.join(extras)}")
        return args
    finally:
        _JSON_ASKED.reset(token)


def _command_parser(parser: argparse.ArgumentParser,
                    args: argparse.Namespace) -> argparse.ArgumentParser:
    """The parser of the (sub-)sub-command that ``args`` chose, ``parser`` if none."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            chosen = action.choices.get(getattr(args, action.dest, None) or "")
            if isinstance(chosen, argparse.ArgumentParser):
                return _command_parser(chosen, args)
    return parser


def _dispatch(handler: Handler, args: argparse.Namespace) -> int:
    try:
        return handler(args)
    except KeyboardInterrupt as exc:
        what = "terminated" if isinstance(exc, Terminated) else "interrupted"
        print(f"wmr: {what}", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    except WmrError as exc:
        if args.debug:
            raise
        line = error_line(exc)
        print(f"wmr: error: {line}", file=sys.stderr)
        _json_error(args, line, exc)
        return 1
    except (OSError, MemoryError) as exc:
        if args.debug:
            raise
        line = error_line(Exception(_environment_error(exc)))
        print(f"wmr: error: {line}", file=sys.stderr)
        _json_error(args, line, exc)
        return 1
    except Exception as exc:
        if args.debug:
            raise
        if _from_memory(exc):  # a module the command loads could not be mapped
            line = error_line(Exception(out_of_memory(_LOADING)))
            print(f"wmr: error: {line}", file=sys.stderr)
            _json_error(args, line, exc)
            return 1
        line = error_line(Exception(f"{type(exc).__name__}: {exc}".replace("\n", " ")))
        print(f"wmr: internal error: {line} (run with --debug for the traceback)",
              file=sys.stderr)
        _json_error(args, f"internal error: {line}", exc)
        return 2


if __name__ == "__main__":
    sys.exit(main())

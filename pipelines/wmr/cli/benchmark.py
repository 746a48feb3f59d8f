"""``wmr benchmark``: the PI stabiliser against its peers and the optimum, side by side."""

from __future__ import annotations

import argparse
from typing import Any

from wmr.cli.shared import add_fmu_options, errors_as_options, json_line

#: ``wmr benchmark``'s options by the field of the request (and of its errors) they fill.
BENCHMARK_OPTIONS: dict[str, str] = {
    "out": "--out", "controllers": "--controllers", "tuned": "--tuned",
    "limit_cases": "--limit-cases", "fmi": "--fmi", "fmu": "--fmu",
}


def _cmd_benchmark(args: argparse.Namespace) -> int:
    from wmr.apps.benchmark import BenchmarkRequest, benchmark_command, format_tables
    from wmr.apps.progress import count_progress

    request = BenchmarkRequest(
        args.scenarios, out=args.out,
        controllers=[c.strip() for c in (args.controllers or "").split(",") if c.strip()],
        tuned=args.tuned, optimal=not args.no_optimal, limit_cases=args.limit_cases,
        fmi=args.fmi, fmu=args.fmu)
    # one bar (a "k/N, about T left" line every 10 s off a terminal), not a line per run
    bar: list[Any] = []

    def progress(runs: int, case: str, label: str) -> None:  # told before each run
        if not bar:
            bar.append(count_progress(runs, "benchmark", "run", False if args.json else None))
        else:  # the last one is done
            bar[0].update(1)
        bar[0].set_postfix_str(f"{case}: {label}", refresh=False)

    try:
        with errors_as_options(BENCHMARK_OPTIONS):
            done = benchmark_command(request, progress)
        if bar:
            bar[0].update(1)
    finally:
        if bar:
            bar[0].close()
    csv_path, pq_path = done.tables
    print(format_tables(done.rows))
    print(f"tables: {csv_path}, {pq_path}; logs: {done.out / 'logs'}")
    if args.json:
        print(json_line(done.rows))
    failed = [r for r in done.rows if r["status"] == "failed"]
    return 1 if failed else 0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``benchmark`` sub-command."""
    b = sub.add_parser(
        "benchmark", help="PI against the peer stabilisers and the optimum",
        description="Run every case of the scenarios with the PI, the tuned PI, Astolfi's and "
                    "the graceful stabiliser (default and tuned gains) on one FMU, solve the "
                    "minimum-time manoeuvre under the same limits, and tabulate time to goal, "
                    "path, energy, torque and heading error (CSV and Parquet in --out, a log "
                    "per run in --out/logs/CONTROLLER/CASE.mcap).")
    b.add_argument("scenarios", nargs="*", metavar="SCENARIO",
                   help="scenario names or TOML files (default fig9 fig10)")
    b.add_argument("--out", metavar="DIR", help="output folder (default runs/benchmark)")
    from wmr.core.control.registry import BUILTIN_NAMES

    b.add_argument("--controllers", metavar="LIST",
                   help="comma-separated rows: a controller's name, or NAME-tuned for its tuned "
                        f"gains (default: {', '.join(BUILTIN_NAMES)} and their -tuned rows), an "
                        "installed plug-in's name too (docs/plugins.md)")
    b.add_argument("--tuned", metavar="FILE.json",
                   help="tuned gains from 'wmr tune --save' (default: the built-in ones)")
    b.add_argument("--no-optimal", action="store_true", help="skip the optimal solves")
    b.add_argument("--limit-cases", type=int, metavar="N", help="only the first N cases")
    b.add_argument("--json", action="store_true",
                   help="the rows as one JSON list on the last line")
    add_fmu_options(b)
    b.set_defaults(handler=_cmd_benchmark)

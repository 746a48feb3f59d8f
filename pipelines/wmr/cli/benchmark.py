"""``wmr benchmark``: the PI stabiliser against its peers and the optimum, side by side."""

from __future__ import annotations

import argparse
from pathlib import Path

from wmr.cli.shared import add_fmu_options, fmu_path, json_line


def _cmd_benchmark(args: argparse.Namespace) -> int:
    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.apps.benchmark import (
        CONTROLLERS,
        DEFAULT_SCENARIOS,
        benchmark_specs,
        format_tables,
        load_tuned,
        run_benchmark,
        write_tables,
    )
    from wmr.apps.progress import count_progress
    from wmr.infra.outputs import check_output

    out = check_output(args.out if args.out else Path("runs") / "benchmark", "--out", "dir")
    specs = benchmark_specs(args.scenarios or list(DEFAULT_SCENARIOS))
    if args.limit_cases is not None:
        specs = specs[: args.limit_cases]
    labels = (list(CONTROLLERS) if not args.controllers
              else [c.strip() for c in args.controllers.split(",") if c.strip()])
    tuned = load_tuned(args.tuned)

    # one bar (a "k/N, about T left" line every 10 s off a terminal), not a line per run
    steps = len(specs) * (len(labels) + (0 if args.no_optimal else 1))
    bar = count_progress(steps, "benchmark", "run", False if args.json else None)
    begun = [False]

    def progress(case: str, label: str) -> None:  # told before each run: the last one is done
        if begun[0]:
            bar.update(1)
        begun[0] = True
        bar.set_postfix_str(f"{case}: {label}", refresh=False)

    try:
        with FmuPlant(fmu_path(args)) as plant:
            rows = run_benchmark(specs, plant, out, labels, tuned,
                                 optimal=not args.no_optimal, progress=progress)
        if begun[0]:
            bar.update(1)
    finally:
        bar.close()
    csv_path, pq_path = write_tables(rows, out)
    print(format_tables(rows))
    print(f"tables: {csv_path}, {pq_path}; logs: {out / 'logs'}")
    if args.json:
        print(json_line(rows))
    failed = [r for r in rows if r["status"] == "failed"]
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

"""Cost of ``wmr report`` on a large batch: the JSON numbers alone, and the full Markdown + PNG.

A synthetic summary of N runs (default 10^5) shaped like a Monte Carlo of ``mc_fig10`` with
random torque limits, friction and loads: a polar start (so the region of attraction is drawn),
six varied inputs, about a tenth of the runs failing or timing out where the friction is high
and the torque limit low.  Each mode runs in a fresh process so that its peak memory is its own.

Run: ``PYTHONPATH=pipelines python benchmarks/report.py [json|full] [N] [REPEATS]`` (both modes,
10^5 runs and 3 repeats by default).  Prints the median wall and CPU time of each mode
(the first repeat includes importing matplotlib and SALib) and the peak memory (max RSS) of its
process.
"""

from __future__ import annotations

import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


def make_summary(folder: Path, n: int, seed: int = 1) -> Path:
    """Write a synthetic ``summary.parquet`` of ``n`` runs into ``folder``."""
    rng = np.random.default_rng(seed)
    r, bearing = rng.uniform(5, 12, n), rng.uniform(0, 360, n)
    sx, sy = r * np.cos(np.radians(bearing)), r * np.sin(np.radians(bearing))
    tau, torque = rng.uniform(0, 1, n), rng.uniform(4, 12, n)
    mass, inertia = rng.normal(25, 3, n), rng.uniform(1, 3, n)
    p_bad = 0.02 + 0.3 * tau * (12 - torque) / 8
    draw = rng.uniform(size=n)
    status = np.where(draw < p_bad / 2, "failed", np.where(draw < p_bad, "timeout",
                                                           "converged"))
    ok = status == "converged"
    ttg = 8 + 0.6 * r + 0.1 * (mass - 25) + 3 * tau + rng.normal(0, 0.2, n)
    ids = [f"{i:07d}-{i * 2654435761 % 16**8:08x}" for i in range(n)]
    table = pa.table({
        "run_id": ids, "name": ["mc"] * n, "base": ["mc"] * n, "variant": [""] * n,
        "start.x_m": sx, "start.y_m": sy, "start.heading_deg": rng.uniform(-180, 180, n),
        "goal.x_m": np.zeros(n), "goal.y_m": np.zeros(n),
        "goal.heading_deg": np.where(sx < 0, 0.0, 180.0),
        "start.r_m": r, "start.bearing_deg": bearing, "params.m": mass,
        "params.I": inertia, "params.tau_c": tau, "limits.torque_max_nm": torque,
        "status": status, "message": np.where(ok, "converged", "stopped").tolist(),
        "final_position_error_m": np.where(ok, 0.04, 0.8) + rng.uniform(0, 0.01, n),
        "final_heading_error_rad": rng.uniform(0, 0.02, n),
        "time_to_goal_s": pa.array(np.where(ok, ttg, np.nan), from_pandas=True),
        "path_length_m": r * 1.2 + rng.uniform(0, 1, n),
        "energy_positive_j": 40 + 2 * mass + rng.normal(0, 2, n),
        "peak_torque_nm": np.minimum(torque, 9.0), "torque_sq_integral_n2m2s": 100 + ttg,
        "mcap": pa.array([None if o else f"runs/{i // 1000:03d}/{k}.mcap"
                          for i, (o, k) in enumerate(zip(ok, ids, strict=True))], pa.string()),
    })
    pq.write_table(table, folder / "summary.parquet", compression="zstd")
    return folder


def _one(mode: str, folder: Path, repeats: int) -> None:
    """Time ``mode`` ``repeats`` times in this process; print one JSON line."""
    from wmr.apps.batch.report import write_report
    from wmr.apps.batch.report_data import report_data

    samples, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        if mode == "json":
            json.dumps(report_data(folder), allow_nan=False)
        else:
            write_report(folder)
        samples.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"mode": mode, "median_s": statistics.median(samples),
                      "samples_s": samples, "median_cpu_s": statistics.median(cpu),
                      "peak_mb": peak_mb}))


def main(argv: list[str]) -> None:
    if argv and argv[0] == "--one":
        _one(argv[1], Path(argv[2]), int(argv[3]))
        return
    modes = [a for a in argv if a in ("json", "full")] or ["json", "full"]
    numbers = [int(a) for a in argv if a.isdigit()]
    n = numbers[0] if numbers else 100_000
    repeats = numbers[1] if len(numbers) > 1 else 3
    with tempfile.TemporaryDirectory() as tmp:
        folder = make_summary(Path(tmp), n)
        print(f"synthetic summary: {n} runs, "
              f"{(folder / 'summary.parquet').stat().st_size / 1e6:.1f} MB")
        for mode in modes:
            out = subprocess.run([sys.executable, __file__, "--one", mode, str(folder),
                                  str(repeats)], check=True, capture_output=True, text=True)
            res = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{mode:>4}: median {res['median_s']:.2f} s over {repeats} "
                  f"({', '.join(f'{s:.2f}' for s in res['samples_s'])}), "
                  f"CPU {res['median_cpu_s']:.2f} s, "
                  f"peak memory {res['peak_mb']:.0f} MB")


if __name__ == "__main__":
    main(sys.argv[1:])

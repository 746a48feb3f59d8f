"""Batch spec loading: the lazy run list against making every run up front.

Loads grid specs of 10^3 to 10^6 runs (three grid axes: ``gains.K_ps``, ``gains.K_is``,
``params.m``) and times, side by side in one process, the load (parse, count, check the
probes: every grid value once) and making every run eagerly (``list(batch.runs)``, what
loading cost before expansion was lazy), the latter only up to 10^4 runs and extrapolated
per run beyond.  Prints medians over ``REPEATS`` and the ratio of each to the eager expansion
of the same spec.

Run: ``python benchmarks/batch_spec.py [REPEATS]`` (default 5).
"""

from __future__ import annotations

import functools
import sys
import tomllib
from typing import Any

from _common import median_seconds
from wmr.apps.batch import parse_batch

#: (K_ps values, K_is values, m values) per spec: 10^3 to 10^6 runs.
SIZES = ((10, 10, 10), (10, 10, 100), (100, 10, 100), (100, 100, 100))
#: Specs up to this many runs are also expanded eagerly; larger ones are extrapolated.
EAGER_MAX = 10_000


def _spec(n_kps: int, n_kis: int, n_m: int) -> dict[str, Any]:
    def values(n: int, first: float, step: float) -> str:
        return ", ".join(f"{first + step * i:.4f}" for i in range(n))

    return tomllib.loads(f"""
name = "bench"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 0.0]
[grid.gains]
K_ps = [{values(n_kps, 0.1, 0.01)}]
K_is = [{values(n_kis, 0.1, 0.01)}]
[grid.params]
m = [{values(n_m, 20.0, 0.1)}]
""")


def _eager(data: dict[str, Any]) -> list[Any]:
    return list(parse_batch(data).runs)


def main(argv: list[str]) -> None:
    repeats = int(argv[0]) if argv else 5
    parse_batch(_spec(2, 2, 2))  # imports (scipy) out of the timings
    per_run_s: float | None = None
    print(f"{'runs':>9}  {'lazy load ms':>12}  {'eager ms':>12}  {'eager / lazy':>12}")
    for sizes in SIZES:
        data = _spec(*sizes)
        n = len(parse_batch(data).runs)
        lazy_s = median_seconds(functools.partial(parse_batch, data), repeats)
        if n <= EAGER_MAX:
            eager_s = median_seconds(functools.partial(_eager, data), max(1, repeats // 2))
            per_run_s = eager_s / n
            note = ""
        else:
            assert per_run_s is not None
            eager_s, note = per_run_s * n, " (extrapolated)"
        print(f"{n:>9}  {lazy_s * 1e3:>12.1f}  {eager_s * 1e3:>12.0f}  {eager_s / lazy_s:>12.0f}"
              f"{note}")
    if per_run_s is not None:
        print(f"making one run: {per_run_s * 1e6:.0f} us (median over the eager expansions)")


if __name__ == "__main__":
    main(sys.argv[1:])

"""Shared helpers of the benchmark scripts: medians of repeated timings and a ratio table."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence


def median_time_per_call(fn: Callable[[int], None], n_calls: int, repeats: int = 7) -> float:
    """Median over ``repeats`` of the seconds per call of ``fn(n_calls)``."""
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(n_calls)
        samples.append((time.perf_counter() - t0) / n_calls)
    return statistics.median(samples)


def median_seconds(fn: Callable[[], object], repeats: int = 5) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls (after one warm-up call)."""
    fn()
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return statistics.median(samples)


def print_table(title: str, rows: Sequence[tuple[str, float]], reference: str) -> None:
    """Print ``rows`` of (name, seconds per call) with the ratio to the ``reference`` row."""
    ref = dict(rows)[reference]
    width = max(len(name) for name, _ in rows)
    print(title)
    print(f"{'what':<{width}}  {'median us/step':>14}  {'ratio to ' + reference:>24}")
    for name, seconds in rows:
        print(f"{name:<{width}}  {seconds * 1e6:>14.3f}  {seconds / ref:>24.2f}")

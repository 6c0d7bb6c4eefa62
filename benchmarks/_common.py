"""Shared helpers for the benchmark scripts: medians, atomic JSON results, resumable sections."""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.stdout.reconfigure(line_buffering=True)  # figures appear as they are measured, even when piped


def median_rate(run: Callable[[], int], repeats: int = 5) -> float:
    """Median of ``repeats`` measurements of ``run()``'s count per wall-clock second."""
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        count = run()
        rates.append(count / (time.perf_counter() - start))
    return statistics.median(rates)


def machine() -> dict[str, Any]:
    import mujoco

    return {
        "python": platform.python_version(),
        "mujoco": mujoco.__version__,
        "cpus": os.cpu_count(),
        "machine": platform.machine(),
    }


class Results:
    """Sections of a benchmark saved to one JSON file, atomically after each section; ``resume`` skips finished ones."""

    def __init__(self, path: Path, resume: bool) -> None:
        self.path = path
        self.data: dict[str, Any] = json.loads(path.read_text()) if resume and path.exists() else {}
        self.data["machine"] = machine()

    def section(self, name: str, compute: Callable[[], dict[str, Any]]) -> dict[str, Any]:
        if name not in self.data:
            self.data[name] = compute()
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_suffix(".json.tmp")
            tmp.write_text(json.dumps(self.data, indent=2))
            os.replace(tmp, self.path)
        return self.data[name]


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a success rate."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def rate(successes: int, n: int) -> dict:
    """A success rate with its count, N and 95 % Wilson interval."""
    low, high = wilson(successes, n)
    return {"successes": successes, "n": n, "rate": successes / n, "ci95": [low, high]}

"""Wall time of the quick benchmark with 1 and 2 worker processes, side by side in one run.

    python benchmarks/evaluate_scaling.py [--repeats 1] [--out results/benchmarks/evaluate_scaling.json]

Runs ``evaluate.py`` (quick protocol, no videos) into temporary folders, checks that
``results.json`` is identical for both worker counts, and prints the speed-up
(goal: >= 1.7x with 2 workers on a 2-core machine).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import Results  # noqa: E402
from benchmarks.evaluate_cost import measured_run  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "benchmarks" / "evaluate_scaling.json")
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    results = Results(args.out, args.resume)
    for repeat in range(args.repeats):

        def measure() -> dict:
            with tempfile.TemporaryDirectory() as folder:
                one, two = Path(folder) / "one", Path(folder) / "two"
                seconds = {
                    f"workers_{n}": measured_run(["--no-video", "--workers", str(n)], out)["wall_seconds"]
                    for n, out in ((1, one), (2, two))
                }
                same = (one / "results.json").read_text() == (two / "results.json").read_text()
            return seconds | {"identical_results": same}

        r = results.section(f"repeat_{repeat}", measure)
        print(
            f"repeat {repeat}: 1 worker {r['workers_1']:.0f} s, 2 workers {r['workers_2']:.0f} s, "
            f"speed-up {r['workers_1'] / r['workers_2']:.2f}x, identical results.json: {r['identical_results']}"
        )
    speedups = [
        results.data[f"repeat_{i}"]["workers_1"] / results.data[f"repeat_{i}"]["workers_2"] for i in range(args.repeats)
    ]
    print(f"median speed-up {statistics.median(speedups):.2f}x  (goal >= 1.7x on 2 cores)")


if __name__ == "__main__":
    main()

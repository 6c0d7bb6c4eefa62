"""What the README's main command costs: wall time and peak memory of the quick benchmark, with its videos and
without, run in turn (with, without, with, ...) so that drift in the machine's speed falls on both alike.

    python benchmarks/evaluate_cost.py [--repeats 2] [--out results/benchmarks/evaluate_cost.json] [--resume]

Each run is ``python evaluate.py`` (one worker, the quick protocol) in a fresh process, into a temporary folder;
peak memory is the operating system's maximum resident set size of that process.  Prints each run, each pair's
ratio of wall times (videos / no videos) and the medians (goals: peak <= 2 GB, ratio <= 1.3).  The two runs'
``results.csv`` must be identical: filming an episode does not change it.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import Results  # noqa: E402


def measured_run(extra: list[str], out: Path) -> dict:
    """One ``python evaluate.py --out out *extra`` run in a fresh process: wall seconds and peak resident memory
    (MiB) of that process."""
    command = [sys.executable, str(ROOT / "evaluate.py"), "--out", str(out), *extra]
    start = time.perf_counter()
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{' '.join(command)} exited with {os.waitstatus_to_exitcode(status)}")
    return {"wall_seconds": seconds, "peak_mib": usage.ru_maxrss / 1024}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "benchmarks" / "evaluate_cost.json")
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    results = Results(args.out, args.resume)
    ratios = []
    for repeat in range(args.repeats):

        def measure() -> dict:
            with tempfile.TemporaryDirectory() as folder:
                videos = measured_run([], Path(folder) / "videos")
                plain = measured_run(["--no-video"], Path(folder) / "plain")
                same = (Path(folder) / "videos" / "results.csv").read_text() == (
                    Path(folder) / "plain" / "results.csv"
                ).read_text()
            return {"videos": videos, "no_video": plain, "identical_results_csv": same}

        r = results.section(f"pair_{repeat}", measure)
        ratio = r["videos"]["wall_seconds"] / r["no_video"]["wall_seconds"]
        ratios.append(ratio)
        print(
            f"pair {repeat}: with videos {r['videos']['wall_seconds']:.0f} s, peak {r['videos']['peak_mib']:.0f} MiB; "
            f"--no-video {r['no_video']['wall_seconds']:.0f} s, peak {r['no_video']['peak_mib']:.0f} MiB; "
            f"ratio {ratio:.2f}; identical results.csv: {r['identical_results_csv']}"
        )
    peaks = [results.data[f"pair_{i}"]["videos"]["peak_mib"] for i in range(args.repeats)]
    print(
        f"median ratio {statistics.median(ratios):.2f} (goal <= 1.3); "
        f"median peak with videos {statistics.median(peaks):.0f} MiB (goal <= 2048)"
    )


if __name__ == "__main__":
    main()

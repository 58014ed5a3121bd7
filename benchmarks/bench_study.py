"""Throughput of a constraint-design study: cases per minute with 1 and 2 local worker processes (pool-1,
pool-2) and through a 2-worker Dask LocalCluster (dask-2) (the same spec each time, a fresh output
directory each time; the local pool's start-up, each worker loading the compiled kernels, is included).

Run: ``.venv/bin/python benchmarks/bench_study.py [--cases 8] [--duration 2.0] [--variant flexible]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from common import print_table

from crane_reference.analysis.study.runner import run_study
from crane_reference.analysis.study.spec import parse_spec


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=8, help="cases (ellipse_a values) per run (default 8)")
    parser.add_argument("--duration", type=float, default=2.0, help="simulated seconds per case (default 2)")
    parser.add_argument("--variant", choices=("flexible", "rigid", "both"), default="flexible")
    args = parser.parse_args()
    values = [round(2.6 + 0.8 * i / max(args.cases - 1, 1), 4) for i in range(args.cases)]
    spec = parse_spec({"variant": args.variant, "duration": args.duration, "step": 1e-3,
                       "vary": {"ellipse_a": {"values": values}}})
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for label, options in (("pool-1", {"workers": 1}), ("pool-2", {"workers": 2}), ("dask-2", None)):
            out = Path(scratch) / label.replace(" ", "_")
            start = time.perf_counter()
            if options is None:
                from distributed import LocalCluster

                with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
                    start = time.perf_counter()  # the cluster's start-up is not the study's
                    table = run_study(spec, out, scheduler=cluster.scheduler_address, progress=False)
            else:
                table = run_study(spec, out, progress=False, **options)
            wall = time.perf_counter() - start
            rows.append({"execution": label, "cases": len(table), "wall_s": wall,
                         "cases_per_minute": 60.0 * len(table) / wall,
                         "mean_case_s": float(table["wall_s"].mean())})
    print_table(f"study throughput: {args.cases} cases of {args.duration:g} s ({args.variant}), "
                f"{os.cpu_count()} CPUs", rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())

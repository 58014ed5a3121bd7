"""Running a study: the cases on a local process pool or a Dask cluster, written as they finish.

Each finished case is appended at once to ``results.csv`` in the output directory (one row per case, the
varied parameters as columns, then the metrics of :mod:`.case`), so Ctrl-C keeps every finished case and
a re-run of the same spec skips the cases whose key is already there.  The cases are the same
computations wherever they run, so a cluster gives the same table as the local pool, bit for bit, but
for the order of the rows (sorted by case at the end) and the wall times.
"""

from __future__ import annotations

import csv
import multiprocessing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from .case import metrics, run_case
from .spec import Case, StudySpec

RESULTS = "results.csv"


def columns(spec: StudySpec) -> list[str]:
    return ["case", "key", *spec.varied, *metrics(spec)]


def finished_keys(out: Path) -> set[str]:
    """Keys of the cases already in ``out``/results.csv."""
    path = out / RESULTS
    if not path.exists():
        return set()
    return set(pd.read_csv(path, usecols=["key"], dtype={"key": str})["key"])


def _local(spec: StudySpec, cases: list[Case], workers: int) -> Iterator[dict[str, object]]:
    """The cases' rows as they finish on ``workers`` local processes, each a fresh interpreter (``spawn``): a fork
    of a caller with threads running (a node's executor, numba's, a test session's) may copy a lock held or
    the collector's state mid-change into the worker."""
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        pending: set[Future] = {pool.submit(run_case, spec, case) for case in cases}
        try:
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    yield future.result()
        finally:
            for future in pending:
                future.cancel()


def _dask(spec: StudySpec, cases: list[Case], address: str) -> Iterator[dict[str, object]]:
    from distributed import Client, as_completed

    with Client(address) as client:
        futures = [client.submit(run_case, spec, case, pure=False) for case in cases]
        try:
            for future in as_completed(futures):
                yield future.result()
        finally:
            client.cancel(futures)


def run_study(spec: StudySpec, out: str | Path, *, workers: int = 1, scheduler: str | None = None,
              progress: bool = True, on_row: Callable[[dict[str, object]], None] | None = None) -> pd.DataFrame:
    """Run the cases of ``spec`` not yet in ``out`` (a local pool of ``workers`` processes, or the Dask
    scheduler at ``scheduler``), appending each to results.csv as it finishes, then sorting the file by case;
    returns the whole table, sorted by case, with ``table.attrs["reused"]`` the cases found done in the file."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    done = finished_keys(out)
    cases = spec.cases()
    todo = [case for case in cases if case.key not in done]
    names = columns(spec)
    path = out / RESULTS
    new_file = not path.exists()
    rows: Iterable[dict[str, object]] = (_dask(spec, todo, scheduler) if scheduler
                                         else _local(spec, todo, workers)) if todo else []
    failed = 0
    with path.open("a", newline="") as handle, tqdm(total=len(todo), desc="cases", unit="case",
                                                    disable=not progress) as bar:
        writer = csv.DictWriter(handle, fieldnames=names, extrasaction="ignore")
        if new_file:
            writer.writeheader()
        for row in rows:
            writer.writerow(row)
            handle.flush()
            failed += not row["feasible"]
            bar.set_postfix(infeasible=failed)
            bar.update()
            if on_row is not None:
                on_row(row)
    _sort_by_case(path)
    table = load_results(out)
    table.attrs["reused"] = len(cases) - len(todo)
    return table


def _sort_by_case(path: Path) -> None:
    """Rewrite the results file with its rows in case order (each row's text as written)."""
    with path.open(newline="") as handle:
        header, *rows = list(csv.reader(handle))
    at = header.index("case")
    rows.sort(key=lambda row: int(row[at]))
    written = path.with_suffix(".sorting")
    with written.open("w", newline="") as handle:
        csv.writer(handle).writerows([header, *rows])
    written.replace(path)


def load_results(out: str | Path) -> pd.DataFrame:
    """results.csv of ``out`` as a table sorted by case."""
    table = pd.read_csv(Path(out) / RESULTS, dtype={"key": str, "reason": str}, keep_default_na=False,
                        na_values=["nan", ""], float_precision="round_trip")
    table["reason"] = table["reason"].fillna("")
    return table.sort_values("case").reset_index(drop=True)

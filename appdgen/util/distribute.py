"""One call that runs a function over work items in parallel: joblib's loky processes or a Dask cluster."""
from __future__ import annotations

import os
from typing import Any, Callable, Iterable, Iterator

from appdgen.errors import AppdgenError

BACKENDS = ("loky", "dask")


def default_jobs() -> int:
    """All cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def resolve_jobs(jobs: int | None) -> int:
    """Worker processes for --jobs as joblib reads n_jobs: None → all cores, -1 → all cores, -2 → all but one,
    …, never fewer than 1; 0 is refused."""
    if jobs is None:
        return default_jobs()
    if jobs == 0:
        raise AppdgenError("--jobs 0: expected a number of workers >= 1, or -1 for all cores (-2: all but one, …)")
    return jobs if jobs > 0 else max(default_jobs() + 1 + jobs, 1)


def check_parallel(jobs: int, backend: str) -> None:
    """Refuse a backend or job count run_unordered cannot use (callers check before writing anything)."""
    if backend not in BACKENDS:
        raise AppdgenError(f"--backend {backend!r}: expected one of {', '.join(BACKENDS)}")
    if jobs < 1:
        raise AppdgenError(f"--jobs {jobs}: must be at least 1")


def run_unordered(fn: Callable[[Any], Any], items: Iterable[Any], jobs: int, backend: str = "loky",
                  scheduler: str | None = None) -> Iterator[Any]:
    """fn(item) for every item, yielded as they finish; jobs == 1 runs in this process."""
    items = list(items)
    check_parallel(jobs, backend)
    if backend == "dask":
        yield from _dask(fn, items, scheduler)
    elif jobs == 1 or len(items) <= 1:
        yield from map(fn, items)
    else:
        from joblib import Parallel, delayed

        parallel = Parallel(n_jobs=min(jobs, len(items)), backend="loky", return_as="generator_unordered")
        yield from parallel(delayed(fn)(item) for item in items)


def _dask(fn: Callable[[Any], Any], items: list[Any], scheduler: str | None) -> Iterator[Any]:
    """Submit to a Dask cluster (a new local one when no scheduler address is given)."""
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise AppdgenError("--backend dask needs dask.distributed: pip install 'appdgen[dask]'") from None
    try:
        client = Client(scheduler) if scheduler else Client(processes=True)
    except OSError as exc:
        raise AppdgenError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
    with client:
        futures = client.map(fn, items, pure=False)
        for future in as_completed(futures):
            yield future.result()

"""`fieldkit sim sweep`: the runs of several experiments in parallel on a Dask cluster.

Every run is a pure function of its `RunSpec` (`experiments.run_one`), so a sweep submits one
task per run, gathers the results as they complete, and puts them back in grid order before
writing: the outputs are the same bytes as `fieldkit sim experiment` running the same grid
sequentially, however the runs were scheduled.

By default the cluster is local and small (2 worker processes, 1 thread each: a Buzz VM is
pure Python, so threads would only queue on the GIL). `scheduler` connects to a running
cluster instead (`dask scheduler` + `dask worker` on other machines); its workers need
fieldkit installed and the behaviour scripts at the same path.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, contextmanager
from typing import TYPE_CHECKING

from fieldkit.errors import FieldkitError
from fieldkit.sim.experiments import Plan, RunResult, RunSpec, run_one

if TYPE_CHECKING:
    from collections.abc import Iterator

    from dask.distributed import Client

#: The default local cluster: small enough for a laptop or a CI runner.
DEFAULT_WORKERS = 2


class SweepError(FieldkitError, RuntimeError):
    """The cluster could not be reached or started."""


@contextmanager
def cluster_client(
    scheduler: str | None = None, workers: int = DEFAULT_WORKERS, processes: bool = True
) -> Iterator[Client]:
    """A Dask client: to `scheduler` if given, else to a new local cluster (closed after)."""
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as e:
            raise SweepError(f"--scheduler {scheduler}: cannot connect: {e}") from None
        try:
            yield client
        finally:
            client.close()
        return
    # The scheduler's HTTP server starts even without a dashboard, on port 8787 unless told
    # otherwise: a free port on the loopback lets sweeps (and tests) run side by side quietly.
    cluster = LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=processes,
        dashboard_address="127.0.0.1:0",
        silence_logs=logging.ERROR,
    )
    try:
        with Client(cluster) as client:
            yield client
    finally:
        cluster.close()


def run_specs(
    client: Client,
    specs: Sequence[RunSpec],
    progress: Callable[[int, int], None] | None = None,
) -> list[RunResult]:
    """Run `specs` on the cluster; the results in the order of `specs`; `progress(done, n)`."""
    from dask.distributed import as_completed

    # pure=False: two identical specs are still two runs (the user asked for both).
    futures = [client.submit(run_one, spec, pure=False) for spec in specs]
    index = {f.key: k for k, f in enumerate(futures)}
    results: list[RunResult | None] = [None] * len(specs)
    done = 0
    for future in as_completed(futures):
        results[index[future.key]] = future.result()
        future.release()
        done += 1
        if progress is not None:
            progress(done, len(specs))
    return [r for r in results if r is not None]


def sweep(
    plans: Sequence[Plan],
    client_factory: Callable[[], AbstractContextManager[Client]] = cluster_client,
    progress: Callable[[int, int], None] | None = None,
) -> list[list[RunResult]]:
    """Run every plan's grid on one cluster; per plan, its results in grid order."""
    specs = [plan.specs() for plan in plans]
    flat = [s for group in specs for s in group]
    with client_factory() as client:
        results = run_specs(client, flat, progress)
    out = []
    start = 0
    for group in specs:
        out.append(results[start : start + len(group)])
        start += len(group)
    return out


__all__ = ["DEFAULT_WORKERS", "SweepError", "cluster_client", "run_specs", "sweep"]

"""What Dask costs a campaign: runs per second through a LocalCluster against the same
runs flown one after another in one plain process, times the number of CPUs.

    python tests/benchmarks/bench_campaign.py --runs 40
    python tests/benchmarks/bench_campaign.py --runs 6 --how processes

Both are measured in this one run, on the same tasks (draws of the smoke campaign), with
the compiled code loaded first on each side (one untimed task in this process, one on
each worker), so the figure is Dask's overhead and the parallel speed-up, not start-up.
A plain pool of as many processes, without Dask, gives the machine's own scaling, so
Dask's overhead shows apart from it. Prints the rates and their ratios (the target:
>= 0.9 of CPUs x the plain process); asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[2]))

from ground.campaign.run import (  # noqa: E402
    batch_size,
    flight_tasks,
    local_cluster,
    run_batch,
    run_task,
)
from ground.campaign.spec import read_campaign  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=40, help="runs in the plain process")
    parser.add_argument("--how", choices=["inprocess", "processes"], default="inprocess")
    parser.add_argument("--workers", type=int, default=len(os.sched_getaffinity(0)))
    args = parser.parse_args()
    from dask.distributed import Client, as_completed

    campaign = read_campaign("smoke")
    import dataclasses

    cpus = args.workers
    campaign = dataclasses.replace(campaign, runs=(args.runs * (cpus + 1) + 2) // 2 + cpus,
                                   how=args.how)
    tasks = flight_tasks(campaign)
    warm, plain, parallel = tasks[0], tasks[1:1 + args.runs], tasks[1 + args.runs:]
    parallel = parallel[:args.runs * cpus]

    run_task(warm)
    start = time.perf_counter()
    for task in plain:
        assert not run_task(task)["error"]
    plain_rate = len(plain) / (time.perf_counter() - start)
    print(f"one plain process: {len(plain)} {args.how} runs, {plain_rate:.2f} runs/s",
          flush=True)

    with local_cluster(cpus) as cluster, Client(cluster) as client:
        workers = list(client.scheduler_info()["workers"])
        for address in workers:  # the compiled code loaded on each worker, untimed
            client.submit(run_task, warm, workers=[address], pure=False).result()
        size = batch_size(len(parallel), len(workers))  # as ivfm campaign sends them
        batches = [parallel[i:i + size] for i in range(0, len(parallel), size)]
        start = time.perf_counter()
        futures = client.map(run_batch, batches, pure=False)
        for future in as_completed(futures):
            assert not any(row["error"] for row in future.result())
        dask_rate = len(parallel) / (time.perf_counter() - start)
    print(f"Dask LocalCluster, {len(workers)} workers: {len(parallel)} {args.how} runs in "
          f"batches of {size}, {dask_rate:.2f} runs/s")
    # The machine's own scaling: the same runs in a plain pool of processes, no Dask.
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(cpus) as pool:
        list(pool.map(run_task, [warm] * cpus))
        start = time.perf_counter()
        assert not any(row["error"] for row in pool.map(run_task, parallel))
        pool_rate = len(parallel) / (time.perf_counter() - start)
    print(f"plain pool of {cpus} processes: {pool_rate:.2f} runs/s")
    print(f"throughput ratio: {dask_rate / (cpus * plain_rate):.3f} of {cpus} x the plain "
          f"process (target >= 0.9); the pool without Dask: "
          f"{pool_rate / (cpus * plain_rate):.3f}; Dask against the pool: "
          f"{dask_rate / pool_rate:.3f}")


if __name__ == "__main__":
    main()

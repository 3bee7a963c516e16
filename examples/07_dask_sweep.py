"""Tutorial 7: a sweep on a Dask cluster.

``vine-nlp sweep SWEEP.toml -o DIR --scheduler ADDRESS`` sends every item of a sweep to
a dask.distributed cluster; the workers need vine_nlp installed and nothing else (the
problems travel with the tasks, the archives come back to this machine). Without
``--scheduler`` this example starts a ``LocalCluster`` on this machine, which is what the
tests do; give the address of a real scheduler (``dask scheduler`` on one machine,
``dask worker ADDRESS`` on the others) to use that instead.

Needs: python3 -m pip install '.[cluster]' (dask.distributed, not in the base install).
Run:  python3 examples/07_dask_sweep.py [--out DIR] [--scheduler tcp://host:8786] [--workers N]
Makes: sweep/ (one archive per item, summary.csv, summary.png), summary.json.
"""

import csv
import logging

from _common import DATA, arguments, vine_nlp, write_summary


def options(p):
    p.add_argument("--scheduler", metavar="ADDRESS", help="a running dask scheduler (default: start a LocalCluster)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="LocalCluster worker processes (default 1)")


def main():
    args = arguments("07_dask_sweep", __doc__.splitlines()[0], options)
    out = args.out
    sweep_dir = out / "sweep"
    cluster = None
    address = args.scheduler
    if address is None:
        from dask.distributed import LocalCluster

        # one thread per worker: each design already keeps a core busy. Worker logs below CRITICAL stay quiet:
        # on a busy machine a worker's heartbeat can meet the scheduler closing at shutdown, and distributed
        # logs that race with a traceback although nothing failed (a failed design comes back as its item's
        # status, through the task, not through the worker's log)
        cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.CRITICAL)
        address = cluster.scheduler_address
    try:
        vine_nlp("sweep", DATA / "small-sweep.toml", "-o", sweep_dir, "--scheduler", address, "--force")
    finally:
        if cluster is not None:
            cluster.close()

    with open(sweep_dir / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    rmse_mm = [float(r["rmse"]) * 10.0 for r in rows]  # the base problem is in cm
    write_summary(
        out,
        {
            "items": len(rows),
            "statuses": sorted({r["status"] for r in rows}),
            "worst_rmse_mm": max(rmse_mm),
            "mean_rmse_mm": sum(rmse_mm) / len(rmse_mm),
            "archives": len(list(sweep_dir.glob("*.h5"))),
            "files": ["sweep/summary.csv", "sweep/summary.png"],
        },
    )


if __name__ == "__main__":  # LocalCluster starts processes: guard the entry point
    main()

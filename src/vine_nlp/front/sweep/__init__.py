"""Design sweeps (../shared/spec/formats.md, "Sweep files"): many design problems, one archive per item.

``run_sweep(load_sweep(path), out_dir)`` solves every item of a sweep with every
method it lists and writes

* ``DIR/<item>.h5``: one result archive per item, all its methods as runs
  (``/runs/nlp``, ``/runs/greedy``), written atomically as soon as the item finishes;
* ``DIR/summary.csv``: one row per item and method, columns ``item``, each grid
  key, ``method``, ``status``, ``rmse``, ``max_error``, ``solve_time_s`` (the
  spec's), then ``iterations``, ``units`` and ``error`` (the exception text of a
  failed run), in grid order, numbers with full precision (``repr``), missing ones
  empty. Written atomically at the end, and when the sweep is interrupted or stops;
* ``DIR/summary.png``: RMSE and solve-time distributions and NLP against greedy
  item by item (:func:`plot_summary`).

The package: :mod:`.executors` (the worker task, the local pool and dask), :mod:`.engine`
(resume, the directory lock, the run), :mod:`.summary` (SweepReport, summary.csv),
:mod:`.figure` (summary.png). dask is imported only when a scheduler address is given.

Execution. The worker task is :func:`solve_chunk`, a few items at a time: each item is solved
by :func:`solve_item` (``design.run_design``, as ``vine-nlp design`` solves a design problem)
and its archive written by the worker (:func:`write_item`: temporary file, fsync, rename); only
the summary's numbers come back. The parent keeps the rows and writes summary.csv and the
figure at the end. Three executors share one code path (:mod:`.executors`):

* ``workers`` > 1 (default ``os.cpu_count()``): local worker processes that live for the
  whole sweep, so each builds a solver once per problem structure and reuses it; items are
  submitted grouped by structure, in chunks of up to 8 that shrink to single items towards the
  end. One task per worker is in flight, so when a worker process dies (a crash in a native
  library, the OOM killer) the suspects are known: they are retried one at a time in a fresh
  pool, and the item that kills its worker alone is failed. Workers die with the sweep (kill -9
  too: Linux's parent-death signal, and a pipe from the parent);
* ``workers`` 0 or 1: in this process, one item after the other;
* ``scheduler`` ADDRESS: ``dask.distributed.Client(ADDRESS)``; the workers need vine_nlp
  installed (the same version). Workers that see the sweep's directory (a shared filesystem,
  recognized by the token in its lock file) write the archives in place; the others send the
  results back and this process writes them (the report says how many). A dask worker that
  dies mid-item is restarted by its nanny and the scheduler runs the task again; a chunk that
  keeps killing workers (dask's KilledWorker) is run again one item per task, and an item that
  does so alone has failed.

Resume. An item whose archive exists, loads, was made from the same problem
source and holds a run of every method is skipped (its rows are rebuilt from the
archive). An archive from the same source missing some method keeps its runs and
only the missing methods are solved. An archive that does not load or comes from
another source (the base file or the grid changed) is redone and replaced.
``force=True`` redoes everything.

Failures. A method that raises fails only its own row (status ``failed``, the
exception text in ``error``); the item's other methods are kept and archived. An
item whose every method failed has no archive (a stale one is removed). Nothing
that happens to one item stops the others. Solver statuses such as ``max_iter``
are not failures: the run is archived with that status.

One sweep per directory: ``DIR/.sweep.lock`` is locked for the whole run; a second
sweep into the same DIR is an InputError (exit 2). A file that cannot be written (a
full disk, a read-only filesystem) stops the sweep with an OutputError (exit 2): the
archives written so far stay, and the same command resumes once space is back.

Ctrl-C or SIGTERM (KeyboardInterrupt): pending items are cancelled, running ones are
stopped (local worker processes are terminated, their temporary files removed), every
finished archive stays intact, the summary of what is on disk is written, and the
KeyboardInterrupt is re-raised with the partial :class:`SweepReport` as its
``sweep_report`` attribute. Running the sweep again continues where it stopped; so it
does after kill -9 (the archives on disk are the resume state).
"""

from __future__ import annotations

from vine_nlp.front.sweep.engine import DirectoryLock, run_sweep
from vine_nlp.front.sweep.executors import (
    LOCK_FILE,
    MAX_CHUNK,
    DaskPool,
    InlinePool,
    LocalPool,
    error_text,
    make_pool,
    solve_chunk,
    solve_item,
    write_item,
)
from vine_nlp.front.sweep.figure import plot_summary
from vine_nlp.front.sweep.summary import (
    SUMMARY_CSV,
    SUMMARY_PNG,
    SweepReport,
    cells,
    format_report,
    make_row,
    method_stats,
    read_summary,
    write_summary,
)

__all__ = [
    "DaskPool", "DirectoryLock", "InlinePool", "LOCK_FILE", "LocalPool", "MAX_CHUNK", "SUMMARY_CSV", "SUMMARY_PNG",
    "SweepReport", "cells", "error_text", "format_report", "make_pool", "make_row", "method_stats", "plot_summary",
    "read_summary", "run_sweep", "solve_chunk", "solve_item", "write_item", "write_summary",
]

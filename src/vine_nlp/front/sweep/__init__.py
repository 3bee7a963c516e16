"""Design sweeps (../shared/spec/formats.md, "Sweep files"): many design problems, one archive per item.

``run_sweep(load_sweep(path), out_dir)`` solves every item of a sweep with every
method it lists and writes

* ``DIR/<item>.h5``: one result archive per item, all its methods as runs
  (``/runs/nlp``, ``/runs/greedy``), written atomically as soon as the item
  finishes, so results stream to disk;
* ``DIR/summary.csv``: one row per item and method, columns ``item``, each grid
  key, ``method``, ``status``, ``rmse``, ``max_error``, ``solve_time_s`` (the
  spec's), then ``iterations``, ``units`` and ``error`` (the exception text of a
  failed run). Rewritten atomically after every finished item (on sweeps so
  large that the rewrite itself takes a while, at most 5% of the time goes to
  it): an interrupted sweep leaves a valid summary of what finished. Rows follow the grid order;
  numbers are written with full precision (``repr``), missing ones as empty cells;
* ``DIR/summary.png``: RMSE and solve-time distributions and NLP against greedy
  item by item (:func:`plot_summary`; its modules are imported in a thread while
  the workers solve, so drawing it is all that is left at the end).

The package: :mod:`.executors` (the worker task, the local pool and dask),
:mod:`.engine` (items, resume, the directory lock, archives streamed to disk),
:mod:`.summary` (SweepReport, summary.csv), :mod:`.figure` (summary.png). dask is
imported only when a scheduler address is given.

Execution. The worker task is the top-level function :func:`solve_item` (a few
items at a time: :func:`solve_chunk`); it returns Results and the parent writes
every file, so a cluster needs no shared filesystem. Every item is solved by
``design.run_design``, the function ``vine-nlp design`` solves a design problem
with. Three executors share one code path (a small adapter: ``submit``,
``wait_first``, ``cancel``, ``close``, ``chunk_size``):

* ``workers`` > 1 (default ``os.cpu_count()``): a ``ProcessPoolExecutor`` whose
  worker processes live for the whole sweep, so each builds a solver once per
  problem structure (``design.transcription.get_solver`` caches per process) and
  reuses it for every later item. The workers are started before anything else
  happens; they are forks of this process when that is safe (one thread, no
  solver used here: the command line's case), so they start with every module
  imported, else they come from a forkserver that imported the solver modules
  once. Items are submitted grouped by structure, in chunks of up to 8 items that
  shrink to single items towards the end; the next chunks go out before the
  parent writes the archives of the last ones, so no worker waits for the disk.
  One task per worker is in flight, so when a worker process dies (a crash in a
  native library, the OOM killer) the suspects are known: they are retried one
  at a time in a fresh pool, and the item that kills its worker alone is failed;
* ``workers`` 0 or 1: in this process, one item after the other;
* ``scheduler`` ADDRESS: ``dask.distributed.Client(ADDRESS)``; dask workers are
  long-lived processes too, so the solver cache works the same way there. The
  workers need vine_nlp installed (the same version), nothing else. A dask
  worker that dies mid-item is restarted by its nanny and the scheduler runs the
  item again; an item that keeps killing workers ends as dask's KilledWorker,
  that item's failure (tests/test_faults.py holds both pools to this).

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
stopped (local worker processes are terminated), every finished archive stays
intact, the summary of what finished is written, and the KeyboardInterrupt is
re-raised with the partial :class:`SweepReport` as its ``sweep_report`` attribute.
Running the sweep again continues where it stopped.
"""

from __future__ import annotations

from vine_nlp.front.sweep.engine import LOCK_FILE, DirectoryLock, run_sweep
from vine_nlp.front.sweep.executors import (
    MAX_CHUNK,
    DaskPool,
    InlinePool,
    LocalPool,
    error_text,
    fork_is_safe,
    make_pool,
    solve_chunk,
    solve_item,
)
from vine_nlp.front.sweep.figure import plot_summary, preload_matplotlib
from vine_nlp.front.sweep.summary import (
    EXTRA_COLUMNS,
    FAILED,
    SPEC_COLUMNS,
    SUMMARY_CSV,
    SUMMARY_PNG,
    SweepReport,
    format_report,
    make_row,
    method_stats,
    read_summary,
    summary_columns,
    write_summary,
)

__all__ = [
    "DaskPool", "DirectoryLock", "EXTRA_COLUMNS", "FAILED", "InlinePool", "LOCK_FILE", "LocalPool", "MAX_CHUNK",
    "SPEC_COLUMNS", "SUMMARY_CSV", "SUMMARY_PNG", "SweepReport", "error_text", "fork_is_safe", "format_report",
    "make_pool", "make_row", "method_stats", "plot_summary", "preload_matplotlib", "read_summary", "run_sweep",
    "solve_chunk", "solve_item", "summary_columns", "write_summary",
]

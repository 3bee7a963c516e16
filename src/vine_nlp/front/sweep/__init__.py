"""Design sweeps (../shared/spec/formats.md, "Sweep files"): many design problems, one archive per item.

``run_sweep(load_sweep(path), out_dir)`` solves every item with every method the sweep lists:

* ``DIR/<item>.h5``: the item's archive, all its methods as runs, written atomically by the
  worker that solved it (:func:`write_item`), as soon as the item finishes;
* ``DIR/summary.csv``: one row per item and method, columns ``item``, each grid key, the spec's
  ``method``, ``status``, ``rmse``, ``max_error``, ``solve_time_s``, then ``iterations``,
  ``units``, ``error``; grid order, full precision, missing numbers empty. Written by the
  parent at the end, and when the sweep is interrupted or stops;
* ``DIR/summary.png``: error and solve-time distributions, NLP against greedy (:func:`plot_summary`).

Execution (:mod:`.executors`): local worker processes (``workers`` > 1, default ``os.cpu_count()``), this process (0 or
1), or a dask scheduler (``scheduler``). Workers send back only the summary's numbers; dask workers that do not see DIR
(no shared filesystem) send the results and this process writes them. A worker that dies mid-item (crash, OOM killer)
loses its items: they run again one at a time, and an item that kills its worker alone has failed. Workers die with the
sweep, kill -9 included.

Resume (:mod:`.engine`): the archives on disk are the state. An item whose archive has the same problem source and a run
of every method is skipped (its rows read back); one missing some method keeps its runs; one that does not load or has
another source is redone; ``force=True`` redoes everything. A method that raises fails its own row only; an item with no
finished run has no archive. One sweep per directory (``DIR/.sweep.lock``). A file that cannot be written stops the
sweep (OutputError, exit 2), finished archives kept. Ctrl-C or SIGTERM: the workers are stopped, the summary of what is
on disk is written, and the KeyboardInterrupt is re-raised with the partial :class:`SweepReport` as ``sweep_report``."""

from __future__ import annotations

from vine_nlp.front.sweep.engine import DirectoryLock, run_sweep
from vine_nlp.front.sweep.executors import MAX_CHUNK, LocalPool, solve_chunk, solve_item, write_item
from vine_nlp.front.sweep.figure import plot_summary
from vine_nlp.front.sweep.summary import SweepReport, cells, format_report, method_stats, read_summary, write_summary

__all__ = ["DirectoryLock", "LocalPool", "MAX_CHUNK", "SweepReport", "cells", "format_report", "method_stats", "plot_summary",
           "read_summary", "run_sweep", "solve_chunk", "solve_item", "write_item", "write_summary"]

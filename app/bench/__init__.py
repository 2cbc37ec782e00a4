"""Benchmark harnesses: the optimiser sweep behind ``handful bench optim``.

One *run* is (method, task, P, seed): ``budget`` trials of suggest → decode → rollout → observe.
Split by concern:

- ``specs``: ``RunSpec`` and the checks on a sweep's arguments;
- ``cache``: the per-run CSV cache (``DIR/runs/``) that makes a sweep resumable;
- ``runner``: one run (``run_one``), trial by trial into the cache;
- ``backends``: many runs (``run_sweep``) in this process, a process pool or on Ray;
- ``stats``: best-so-far per budget, head-to-head Welch tests;
- ``report``: DIR/results.csv, DIR/summary.md and DIR/curves.png.

The harness sits above the libraries (``app.optim``, ``app.sim``, ``app.policy``); they
import nothing from it.
"""

from __future__ import annotations

from app.bench.backends import run_sweep
from app.bench.cache import (
    RUN_COLUMNS,
    RunBusy,
    cached_rows,
    read_run,
    run_dir,
    stored_rows,
    trials_done,
    write_part,
    write_run,
)
from app.bench.report import (
    RESULT_COLUMNS,
    head_to_head_markdown,
    plot_curves,
    read_results_csv,
    summary_markdown,
    write_outputs,
    write_results_csv,
)
from app.bench.runner import objective_fn, run_one, run_rl
from app.bench.specs import (
    RL_LEVELS,
    SWEEP_METHODS,
    TASKS,
    RunSpec,
    make_specs,
    task_dim,
    validate,
)
from app.bench.stats import best_at, head_to_head, result_rows
from app.policy import (
    COMMAND_HOLDS,
    OBJECTIVE_RULES,
    PAPER_COMMAND_HOLD,
    PAPER_OBJECTIVE_RULE,
    PAPER_PRESET,
)

__all__ = [
    "COMMAND_HOLDS",
    "OBJECTIVE_RULES",
    "PAPER_COMMAND_HOLD",
    "PAPER_OBJECTIVE_RULE",
    "PAPER_PRESET",
    "RESULT_COLUMNS",
    "RL_LEVELS",
    "RUN_COLUMNS",
    "SWEEP_METHODS",
    "TASKS",
    "RunBusy",
    "RunSpec",
    "best_at",
    "cached_rows",
    "head_to_head",
    "head_to_head_markdown",
    "make_specs",
    "objective_fn",
    "plot_curves",
    "read_results_csv",
    "read_run",
    "result_rows",
    "run_dir",
    "run_one",
    "run_rl",
    "run_sweep",
    "stored_rows",
    "summary_markdown",
    "task_dim",
    "trials_done",
    "validate",
    "write_outputs",
    "write_part",
    "write_results_csv",
    "write_run",
]

"""Running a sweep's specs: in this process, on a local process pool, or on Ray."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from app.bench.cache import RunBusy, cached_rows, run_dir, stored_rows, trials_done, write_run
from app.bench.runner import run_one
from app.bench.specs import RunSpec
from app.optim import SettingsError


def _run_one_in_worker(spec: RunSpec, out: str | None) -> list[dict[str, Any]]:
    return run_one(spec, Path(out) if out is not None else None)


def run_sweep(
    specs: Sequence[RunSpec],
    out: Path,
    *,
    backend: str = "local",
    address: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    busy: list[RunBusy] | None = None,
    stored: Sequence[RunSpec] = (),
) -> dict[RunSpec, list[dict[str, Any]]]:
    """Run every spec not already cached in ``out``; return all runs' rows, plus whatever
    ``out`` holds of the ``stored`` specs (finished or not; never run here): the other runs
    of the same grid that the outputs show beside this invocation's.

    Backends: ``local`` (a process pool over ``workers`` cores, default all) or ``ray``
    (``ray.init(address)``; a local Ray instance when ``address`` is None). Progress bars count
    runs and trials (trials are read from the run caches as they grow).

    A run another process is writing (``RunBusy``, ``app.bench.cache.run_lock``) is left to it:
    with a ``busy`` list the error is appended there and the sweep goes on without that run
    (it is not in the result); without one it is raised.
    """

    def left_to_another(exc: RunBusy) -> None:
        if busy is None:
            raise exc
        busy.append(exc)

    from tqdm import tqdm

    if backend not in ("local", "ray"):
        raise SettingsError(f"backend must be 'local' or 'ray', got {backend!r}")
    out = Path(out)
    run_dir(out).mkdir(parents=True, exist_ok=True)
    results: dict[RunSpec, list[dict[str, Any]]] = {}
    todo = []
    for s in specs:
        rows = cached_rows(s, out)
        if rows is None:
            todo.append(s)
        else:
            results[s] = rows
    todo.sort(key=RunSpec.cost_rank)
    n_workers = max(1, workers or os.cpu_count() or 1)
    total_trials = sum(s.budget for s in specs)
    bar_runs = tqdm(total=len(specs), desc="runs", unit="run", disable=not progress, position=0)
    bar_trials = tqdm(
        total=total_trials, desc="trials", unit="trial", disable=not progress, position=1
    )
    bar_runs.update(len(results))

    def refresh() -> None:
        done = sum(s.budget if s in results else trials_done(s, out) for s in specs)
        bar_trials.update(done - bar_trials.n)

    refresh()
    try:
        if todo and backend == "local" and n_workers == 1:
            for s in todo:
                try:
                    results[s] = run_one(s, out)
                except RunBusy as exc:
                    left_to_another(exc)
                bar_runs.update(1)
                refresh()
        elif todo and backend == "local":
            from concurrent.futures import FIRST_COMPLETED, wait

            from app.procs import process_pool

            with process_pool(min(n_workers, len(todo))) as ex:
                futs = {ex.submit(_run_one_in_worker, s, str(out)): s for s in todo}
                pending = set(futs)
                while pending:
                    finished, pending = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
                    for fut in finished:
                        try:
                            results[futs[fut]] = fut.result()
                        except RunBusy as exc:
                            left_to_another(exc)
                        bar_runs.update(1)
                    refresh()
        elif todo:
            import ray

            started = not ray.is_initialized()
            if started:
                if address:
                    ray.init(address=address, log_to_driver=False)
                else:
                    ray.init(num_cpus=n_workers, log_to_driver=False, include_dashboard=False)
            try:
                remote = ray.remote(num_cpus=1)(_run_one_in_worker)
                refs = {remote.remote(s, str(out.resolve())): s for s in todo}
                pending_refs = list(refs)
                while pending_refs:
                    ready, pending_refs = ray.wait(pending_refs, num_returns=1, timeout=1.0)
                    for ref in ready:
                        s = refs[ref]
                        try:
                            results[s] = ray.get(ref)  # Ray's error is also a RunBusy
                        except RunBusy as exc:
                            left_to_another(exc)
                            bar_runs.update(1)
                            continue
                        # On a cluster the workers' disks are not ours: cache here too.
                        if cached_rows(s, out) is None:
                            write_run(s, out, results[s])
                        bar_runs.update(1)
                    refresh()
            finally:
                if started:
                    ray.shutdown()
    finally:
        bar_trials.close()
        bar_runs.close()
    ran = {s.key for s in results}
    for s in stored:
        if s.key not in ran and (rows := stored_rows(s, out)):
            results[s] = rows
    return results

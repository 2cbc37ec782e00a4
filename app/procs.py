"""Worker processes: the one way handful starts them (stdlib only, cheap to import)."""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor

PARENT_POLL_S = 0.5  # how often a pool process checks that the process that made it lives


def _exit_with_parent(parent_pid: int, poll_s: float) -> None:
    """Exit this process soon after ``parent_pid`` dies (however it died).

    A pool process otherwise outlives a parent killed with SIGKILL (or by the OOM killer):
    it holds its own end of the task queue, never sees EOF and waits forever.
    """

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent_pid:  # re-parented: the parent is gone
                os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _pool_init(
    parent_pid: int, poll_s: float, initializer: Callable[..., None] | None, initargs: tuple
) -> None:
    _exit_with_parent(parent_pid, poll_s)
    if initializer is not None:
        initializer(*initargs)


def process_pool(
    max_workers: int,
    initializer: Callable[..., None] | None = None,
    initargs: tuple = (),
) -> ProcessPoolExecutor:
    """A ``spawn`` process pool whose processes exit when the process that made it dies.

    The one way handful starts worker processes (rollout pools, optimiser sweeps, sim
    workers): ``spawn``, never ``fork`` (threads may be running), and no orphans left
    behind when a sweep or a worker is killed.
    """
    return ProcessPoolExecutor(
        max_workers=max_workers,
        mp_context=mp.get_context("spawn"),
        initializer=_pool_init,
        initargs=(os.getpid(), PARENT_POLL_S, initializer, initargs),
    )


def set_torch_threads(n: int) -> None:
    """Set torch's intra-op thread count for this whole process (``Settings.torch_threads``).

    Called once by the entry points that run optimisers (the server's ``create_app``, each
    sweep run, the benchmarks); the libraries (``app.optim``) never set it themselves.
    """
    import torch

    if torch.get_num_threads() != n:
        torch.set_num_threads(n)

"""Optimiser work off the server's process, bounded in time and cancellable.

A suggestion (``trials.ask``) and the GP view of ``GET /model`` (``data.model_view``) run in a
small pool of spawn processes (``app.procs.process_pool``). ``ComputeRunner.call`` waits for
a job at most ``timeout_s`` (``HANDFUL_SUGGEST_TIMEOUT_S``) and while the caller still wants
it: past the budget, or once the client has gone, the pool's processes are killed (the only
way to stop a GP fit or an acquisition search midway), a fresh pool is started, and the caller
gets ``ComputeTimeout`` (503 with Retry-After) or ``ComputeCancelled``. Nothing is stored.

Each compute process keeps the optimisers its suggestions fitted (the newest
``FITTED_CACHE`` of them, keyed by method, settings, seed and observations): ``GET /model``
on the same observations reuses that fit instead of fitting the GP again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from app.service.errors import ServiceError

log = logging.getLogger("handful.compute")
T = TypeVar("T")
FITTED_CACHE = 16
START_TIMEOUT_S = 120.0  # a fresh compute process's start-up (spawn, torch and BoTorch import)


class ComputeTimeout(ServiceError):
    """The optimiser ran past its time budget; it was stopped and nothing was stored (503)."""

    status_code = 503
    code = "compute_timeout"
    retry_after_s = 5


class ComputeCancelled(ServiceError):
    """The client left before the optimiser finished; it was stopped (nobody gets a reply)."""

    status_code = 499
    code = "cancelled"


# --- in the compute process ----------------------------------------------------------------------
_fitted: OrderedDict[str, Any] = OrderedDict()


def fit_key(inputs: Any) -> str:
    """What a fitted model depends on: method, dim, seed, settings, observations in order and
    the sim prior's data (if any)."""
    prior = inputs.spec.prior
    blob = json.dumps(
        [
            inputs.spec.method,
            inputs.dim,
            inputs.spec.seed,
            sorted(inputs.spec.kwargs().items()),
            [[list(o.theta), o.value, o.sem] for o in inputs.observations],
            None if prior is None else [prior.theta.tolist(), prior.objective.tolist()],
        ],
        default=str,
    )
    return hashlib.sha256(blob.encode()).hexdigest()


def remember(inputs: Any, opt: Any) -> None:
    key = fit_key(inputs)
    _fitted[key] = opt
    _fitted.move_to_end(key)
    while len(_fitted) > FITTED_CACHE:
        _fitted.popitem(last=False)


def fitted(inputs: Any) -> Any | None:
    """The optimiser a suggestion fitted on exactly these observations, if this process has it."""
    return _fitted.get(fit_key(inputs))


def suggest_job(inputs: Any, n: int) -> tuple[Any, Any, Any, float, dict[str, Any]]:
    """``trials.ask`` in the compute process; its fitted optimiser is kept for ``/model``.
    The last item: what the suggestion leaned on (``Optimizer.suggestion_basis()``)."""
    from app.service.trials import ask

    timings: dict[str, float] = {}
    basis: dict[str, Any] = {}
    thetas, mean, std = ask(
        inputs, n, timings=timings, on_fitted=lambda o: remember(inputs, o), basis=basis
    )
    return thetas, mean, std, timings.get("optimizer_s", 0.0), basis


def model_job(inputs: Any, incumbent: list[float], n_points: int) -> tuple[dict[str, Any], bool]:
    """``data.model_view`` on the cached fit when there is one; (view, whether it was cached)."""
    from app.service.data import model_view
    from app.service.trials import rebuild_optimizer

    opt = fitted(inputs)
    hit = opt is not None
    if opt is None:
        opt = rebuild_optimizer(inputs)
        remember(inputs, opt)
    return model_view(opt, inputs, incumbent, n_points), hit


#: methods whose work grows at most linearly with the observations: run in the caller's
#: thread (no process hop, no start-up wait), never near a time budget
INLINE_METHODS = frozenset({"random", "cem"})


def inline(inputs: Any) -> bool:
    """Whether this optimiser's work is cheap enough to run in the request's own thread."""
    return inputs.spec.method in INLINE_METHODS


def _warm() -> None:
    import app.optim  # noqa: F401  (torch and BoTorch, imported once per process)


# --- in the server ---------------------------------------------------------------------------
class ComputeRunner:
    """Runs jobs in spawn processes, each within ``timeout_s`` and only while wanted.

    ``workers`` single-process pools; a job with a ``shard`` (the experiment's id) always runs
    in the same one, so ``/model`` finds the fit its experiment's last suggestion left there.
    """

    def __init__(self, workers: int = 2, timeout_s: float = 120.0) -> None:
        self.workers = workers
        self.timeout_s = timeout_s
        self._pools: list[Any] = [None] * workers
        self._warming: list[Future[None] | None] = [None] * workers
        self._lock = threading.Lock()

    def _get_pool(self, slot: int) -> Any:
        from app.procs import process_pool

        with self._lock:
            if self._pools[slot] is None:
                self._pools[slot] = process_pool(1)
                self._warming[slot] = self._pools[slot].submit(_warm)
            return self._pools[slot]

    def warm(self, slot: int | None = None) -> None:
        """Start the processes and import the optimisers now (not in the first request)."""
        for i in range(self.workers) if slot is None else (slot,):
            self._get_pool(i)

    def _wait_started(self, slot: int, cancelled: threading.Event | None) -> None:
        """Wait (up to START_TIMEOUT_S) for a fresh process to import the optimisers: its
        start-up is not the job's, and does not count against the job's budget."""
        warming = self._warming[slot]
        deadline = time.monotonic() + START_TIMEOUT_S
        while warming is not None and not warming.done():
            if cancelled is not None and cancelled.is_set():
                raise ComputeCancelled("the client left while the optimiser process started")
            if time.monotonic() > deadline:
                raise ComputeTimeout("the optimiser process did not start; retry")
            time.sleep(0.05)

    def _kill(self, slot: int, pool: Any, *, restart: bool = True) -> None:
        with self._lock:
            if self._pools[slot] is pool:
                self._pools[slot] = None
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            proc.kill()
        pool.shutdown(wait=False, cancel_futures=True)
        if restart:
            self.warm(slot)  # the next request should not wait for torch's import

    def call(
        self,
        fn: Callable[..., T],
        *args: Any,
        shard: int = 0,
        cancelled: threading.Event | None = None,
        what: str = "the optimiser",
        in_thread: bool = False,
    ) -> T:
        """``fn(*args)`` in the compute process of ``shard``; ComputeTimeout past
        ``timeout_s``, ComputeCancelled once ``cancelled`` is set (the process is killed
        either way, and a fresh one started). ``in_thread``: just call it here (cheap work,
        see ``inline``)."""
        if in_thread:
            return fn(*args)
        slot = shard % self.workers
        pool = self._get_pool(slot)
        self._wait_started(slot, cancelled)
        deadline = time.monotonic() + self.timeout_s
        try:
            future: Future[T] = pool.submit(fn, *args)
        except (BrokenProcessPool, RuntimeError):  # killed meanwhile by another call
            self._kill(slot, pool, restart=False)
            pool = self._get_pool(slot)
            future = pool.submit(fn, *args)
        while True:
            try:
                return future.result(timeout=0.05)
            except FutureTimeout:
                pass
            except BrokenProcessPool:
                self._kill(slot, pool)
                raise ComputeTimeout(
                    f"{what} was stopped (its process ended: another request ran past its "
                    "time budget, or it ran out of memory); nothing was stored, retry"
                ) from None
            if cancelled is not None and cancelled.is_set():
                self._kill(slot, pool)
                log.info("%s stopped: the client left", what)
                raise ComputeCancelled(f"{what} was stopped: the client left")
            if time.monotonic() > deadline:
                self._kill(slot, pool)
                log.warning("%s stopped after its %.0f s budget", what, self.timeout_s)
                raise ComputeTimeout(
                    f"{what} did not finish within its {self.timeout_s:g} s budget "
                    "(HANDFUL_SUGGEST_TIMEOUT_S) and was stopped; nothing was stored. Fewer "
                    "observations or smaller optimizer_settings make it faster"
                )

    def shutdown(self) -> None:
        with self._lock:
            pools, self._pools = self._pools, [None] * self.workers
        for slot, pool in enumerate(pools):
            if pool is not None:
                self._kill(slot, pool, restart=False)

"""What the sim and hardware workers share: retries, lease heartbeats, clean shutdown."""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import httpx

log = logging.getLogger("handful.worker")
T = TypeVar("T")

TRANSIENT_STATUS = {408, 425, 429, 500, 502, 503, 504}


class PermanentError(RuntimeError):
    """The server refused a request for good (4xx): retrying cannot help."""

    def __init__(self, message: str, status_code: int | None = None) -> None:
        super().__init__(message)
        self.status_code = status_code


def default_worker_id(kind: str) -> str:
    """`<kind>-<host>-<pid>`: unique per process, readable in the audit log."""
    return f"{kind}-{socket.gethostname()}-{os.getpid()}"


def _status_of(exc: BaseException) -> int | None:
    for attr in ("status_code", "status"):
        code = getattr(exc, attr, None)
        if isinstance(code, int):
            return code
    response = getattr(exc, "response", None)
    code = getattr(response, "status_code", None)
    return code if isinstance(code, int) else None


def is_transient(exc: BaseException) -> bool:
    """Connection trouble, timeouts and 5xx/429 are worth retrying; other errors are not."""
    if isinstance(exc, httpx.TransportError):
        return True
    code = _status_of(exc)
    return code in TRANSIENT_STATUS


class StopRequested(RuntimeError):
    """A retry loop gave up because the worker is stopping."""


class StopFlag:
    """Set by SIGTERM/SIGINT: finish what is in flight, claim nothing new, exit 0."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self.signals = 0
        self.on_force: list[Callable[[], None]] = []

    def install(self) -> None:
        """Handle SIGTERM and SIGINT (main thread only). A second signal exits at once."""

        def handler(signum: int, _frame: Any) -> None:
            self.signals += 1
            if self.signals > 1:
                log.warning("second signal: aborting and exiting now")
                for hook in self.on_force:
                    hook()
                os._exit(1)
            log.info("signal %d: finishing trials in flight, then exiting", signum)
            self._event.set()

        signal.signal(signal.SIGTERM, handler)
        signal.signal(signal.SIGINT, handler)

    def set(self) -> None:
        """Ask the worker to stop."""
        self._event.set()

    def is_set(self) -> bool:
        """Whether a stop was asked for."""
        return self._event.is_set()

    def wait(self, timeout: float) -> bool:
        """Sleep up to `timeout` s; True (early) when a stop is asked for."""
        return self._event.wait(timeout)


def retry(
    call: Callable[[], T],
    *,
    what: str,
    stop: StopFlag | None = None,
    deadline_s: float = 600.0,
    first_delay_s: float = 0.2,
    max_delay_s: float = 5.0,
) -> T:
    """Run `call`, retrying transient HTTP failures with capped exponential backoff.

    Gives up after `deadline_s` (raises the last error), or with StopRequested once `stop` is
    set (pass it only for calls not worth finishing, like a claim). Non-transient errors are
    raised at once as PermanentError.
    """
    start = time.monotonic()
    delay = first_delay_s
    attempt = 0
    while True:
        attempt += 1
        try:
            return call()
        except Exception as exc:
            if not is_transient(exc):
                raise PermanentError(f"{what}: {exc}", _status_of(exc)) from exc
            if time.monotonic() - start > deadline_s:
                raise
            if attempt == 1 or attempt % 10 == 0:
                log.warning("%s failed (%s: %s); retrying", what, exc.__class__.__name__, exc)
            if stop is not None:
                if stop.wait(delay):
                    raise StopRequested(f"{what}: worker stopping") from exc
            else:
                time.sleep(delay)
            delay = min(max_delay_s, delay * 2.0)


class LeaseKeeper:
    """A daemon thread that heartbeats every lease this worker holds.

    `heartbeat(lease_id)` is the client call; a lease the server calls lost (a 4xx) is dropped
    and remembered in `lost`, so the worker does not bother posting a result the server will
    refuse (it posts anyway for hardware, so the refusal is on record).
    """

    def __init__(
        self,
        heartbeat: Callable[[str], Any],
        interval_s: float,
        on_lost: Callable[[str], Any] | None = None,
    ) -> None:
        self._heartbeat = heartbeat
        self.interval_s = interval_s
        #: called (on the heartbeat thread) with a lease the server calls lost, e.g. revoked
        #: because an operator stopped the trial: the hardware worker aborts the driver
        self._on_lost = on_lost
        self._leases: set[str] = set()
        self.lost: set[str] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lease-heartbeat", daemon=True)

    def start(self) -> None:
        """Start heartbeating."""
        self._thread.start()

    def add(self, lease_id: str) -> None:
        """Keep this lease alive from now on."""
        with self._lock:
            self._leases.add(lease_id)

    def remove(self, lease_id: str) -> None:
        """Stop heartbeating this lease (its result is posted)."""
        with self._lock:
            self._leases.discard(lease_id)

    def stop(self) -> None:
        """Stop the thread."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def beat_once(self) -> None:
        """Heartbeat every held lease once."""
        with self._lock:
            leases = sorted(self._leases)
        for lease_id in leases:
            try:
                self._heartbeat(lease_id)
            except Exception as exc:
                if is_transient(exc):
                    log.warning("heartbeat for lease %s failed (%s)", lease_id, exc)
                    continue
                log.error("lease %s lost: %s", lease_id, exc)
                with self._lock:
                    self._leases.discard(lease_id)
                    self.lost.add(lease_id)
                if self._on_lost is not None:
                    self._on_lost(lease_id)

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            self.beat_once()

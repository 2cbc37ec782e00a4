"""The run cache: ``DIR/runs/<key>.part.csv`` grows one line per finished trial (with θ); a
finished run is renamed ``<key>.csv``. An interrupted run resumes from the lines before a cut.
While a process writes a run it holds ``<key>.lock``, so a second one cannot write it too."""

from __future__ import annotations

import csv
import fcntl
import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from app.bench.specs import RunSpec

RUN_COLUMNS = ("trial", "objective", "wall_s", "theta")


def run_dir(out: Path) -> Path:
    """Where per-run caches live."""
    return Path(out) / "runs"


def read_run(path: Path) -> list[dict[str, Any]]:
    """Rows of one run's cache file: trial, objective, wall_s, theta (list)."""
    rows = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            try:
                row = {
                    "trial": int(r["trial"]),
                    "objective": float(r["objective"]),
                    "wall_s": float(r["wall_s"]),
                    "theta": json.loads(r["theta"]),
                }
            except (TypeError, ValueError):
                break  # a line cut short by an interruption: resume from the rows before it
            if row["trial"] != len(rows) + 1:
                break
            rows.append(row)
    return rows


def cached_rows(spec: RunSpec, out: Path) -> list[dict[str, Any]] | None:
    """The finished run's first ``budget`` rows, or None when not cached (long enough)."""
    path = run_dir(out) / f"{spec.key}.csv"
    if not path.exists():
        return None
    rows = read_run(path)
    return rows[: spec.budget] if len(rows) >= spec.budget else None


def stored_rows(spec: RunSpec, out: Path) -> list[dict[str, Any]]:
    """Whatever ``out`` holds of ``spec``: a finished run's rows, else an unfinished run's rows
    so far (possibly none), at most ``budget``."""
    for name in (f"{spec.key}.csv", f"{spec.key}.part.csv"):
        path = run_dir(out) / name
        if path.exists():
            return read_run(path)[: spec.budget]
    return []


def run_line(row: dict[str, Any]) -> list[Any]:
    """One cache line of a trial's row (objective exact, θ as JSON)."""
    return [
        row["trial"],
        repr(float(row["objective"])),
        f"{row['wall_s']:.4f}",
        json.dumps(row["theta"]),
    ]


def write_part(path: Path, rows: list[dict[str, Any]]) -> None:
    """Start a part file holding ``rows`` (resuming a longer run from a shorter finished one)."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(RUN_COLUMNS)
        w.writerows(run_line(r) for r in rows)


def write_run(spec: RunSpec, out: Path, rows: list[dict[str, Any]]) -> None:
    """Store a finished run's rows as ``runs/<key>.csv`` (atomically) and drop its part file."""
    run_dir(out).mkdir(parents=True, exist_ok=True)
    final = run_dir(out) / f"{spec.key}.csv"
    tmp = final.with_suffix(".tmp")
    write_part(tmp, rows)
    os.replace(tmp, final)
    (run_dir(out) / f"{spec.key}.part.csv").unlink(missing_ok=True)


def trials_done(spec: RunSpec, out: Path) -> int:
    """How many trials of ``spec`` are on disk (finished or in progress)."""
    for name in (f"{spec.key}.csv", f"{spec.key}.part.csv"):
        path = run_dir(out) / name
        if path.exists():
            try:
                with open(path) as fh:
                    return min(spec.budget, max(0, sum(1 for _ in fh) - 1))
            except OSError:
                return 0
    return 0


class RunBusy(RuntimeError):
    """Another process is writing this run (it holds the run's lock)."""


@contextmanager
def run_lock(spec: RunSpec, out: Path) -> Iterator[None]:
    """Hold ``runs/<key>.lock`` while this process writes the run: an exclusive ``flock``, which
    the system lets go however the process ends (so a killed run never blocks the next). Raises
    RunBusy, naming the holder's pid, when another process holds it: two writers would
    interleave their trials in one part file."""
    run_dir(out).mkdir(parents=True, exist_ok=True)
    path = run_dir(out) / f"{spec.key}.lock"
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise RunBusy(
                f"run {spec.key} in {out} is being written by another process (pid {holder}): "
                "wait for it, or run other cells (two writers would mix their trials)"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the last holder removed this file as we opened it: lock the new one
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        path.unlink(missing_ok=True)
        os.close(fd)

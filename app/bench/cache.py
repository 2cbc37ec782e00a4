"""The run cache: ``DIR/runs/<key>.part.csv`` grows one line per finished trial (with θ); a
finished run is renamed ``<key>.csv``. An interrupted run resumes from the lines before a cut."""

from __future__ import annotations

import csv
import json
import os
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

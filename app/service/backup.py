"""Backups of a SQLite data folder that are consistent while the server runs, and restores.

``backup(data_dir, dest)`` copies the database with SQLite's online backup API (every page of
one consistent snapshot, the WAL's committed transactions included, which a plain file copy
misses), then the artifact files that snapshot refers to (artifacts are written before the
transaction that records them commits, and never changed, so each one the snapshot names is
complete on disk), and writes ``manifest.json`` (row counts, each file's SHA-256).
``restore(src, data_dir)`` checks the manifest and the database's integrity, then puts both in
place in an empty (or ``force``d) data folder.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sqlite3
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from app.service.errors import Conflict, InvalidInput

DB_NAME = "handful.db"
MANIFEST = "manifest.json"
_COUNTED = ("experiments", "trials", "measurements", "audit_log", "artifacts", "users", "tokens")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _counts(conn: sqlite3.Connection) -> dict[str, int]:
    return {t: conn.execute(f"SELECT count(*) FROM {t}").fetchone()[0] for t in _COUNTED}


def backup(data_dir: Path, dest: Path, *, pages_per_step: int = 256) -> dict[str, Any]:
    """Copy ``data_dir``'s database and artifacts to the new folder ``dest``; the manifest.

    Safe while the server runs: the backup API copies ``pages_per_step`` pages at a time and
    starts again if a writer changed the database meanwhile, so writers are never held up
    for long and the copy is one committed state."""
    src_db = data_dir / DB_NAME
    if not src_db.is_file():
        raise InvalidInput(f"no database at {src_db}")
    if dest.exists() and any(dest.iterdir()):
        raise Conflict(f"{dest} exists and is not empty; back up into a new folder")
    dest.mkdir(parents=True, exist_ok=True)
    dest_db = dest / DB_NAME
    source = sqlite3.connect(f"file:{src_db}?mode=ro", uri=True)
    target = sqlite3.connect(dest_db)
    try:
        source.backup(target, pages=pages_per_step)
        target.execute("PRAGMA journal_mode=DELETE")  # one self-contained file
        counts = _counts(target)
        paths = [row[0] for row in target.execute("SELECT path FROM artifacts ORDER BY id")]
    finally:
        target.close()
        source.close()
    os.chmod(dest_db, 0o600)
    files: dict[str, str] = {}
    missing: list[str] = []
    for rel in paths:
        src = data_dir / "artifacts" / rel
        if not src.is_file():
            missing.append(rel)
            continue
        out = dest / "artifacts" / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, out)
        files[rel] = _sha256(out)
    manifest = {
        "made_at": datetime.now(UTC).isoformat(),
        "source": str(data_dir.resolve()),
        "database": {"file": DB_NAME, "sha256": _sha256(dest_db), "rows": counts},
        "artifacts": files,
        "missing_artifacts": missing,
    }
    (dest / MANIFEST).write_text(json.dumps(manifest, indent=1, sort_keys=True))
    return manifest


def verify(src: Path) -> dict[str, Any]:
    """The manifest of backup ``src``, checked: file hashes and SQLite's integrity_check."""
    try:
        manifest = json.loads((src / MANIFEST).read_text())
    except (OSError, ValueError) as exc:
        raise InvalidInput(f"{src} is not a handful backup: {exc}") from None
    db = src / manifest["database"]["file"]
    if _sha256(db) != manifest["database"]["sha256"]:
        raise InvalidInput(f"{db} does not match the manifest (changed or damaged)")
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        result = conn.execute("PRAGMA integrity_check").fetchone()[0]
    finally:
        conn.close()
    if result != "ok":
        raise InvalidInput(f"{db} fails SQLite's integrity check: {result}")
    for rel, digest in manifest["artifacts"].items():
        if _sha256(src / "artifacts" / rel) != digest:
            raise InvalidInput(f"artifact {rel} does not match the manifest")
    return manifest


def restore(src: Path, data_dir: Path, *, force: bool = False) -> dict[str, Any]:
    """Put backup ``src`` in ``data_dir`` (stop the server first). Refuses a data folder that
    holds a database unless ``force`` (that database and its artifacts are then replaced)."""
    manifest = verify(src)
    target_db = data_dir / DB_NAME
    if target_db.exists() and not force:
        raise Conflict(f"{target_db} exists; stop the server and pass --force to replace it")
    data_dir.mkdir(parents=True, exist_ok=True)
    for suffix in ("-wal", "-shm"):
        Path(f"{target_db}{suffix}").unlink(missing_ok=True)
    tmp = data_dir / (DB_NAME + ".restoring")
    shutil.copy2(src / DB_NAME, tmp)
    os.chmod(tmp, 0o600)
    os.replace(tmp, target_db)
    artifacts = data_dir / "artifacts"
    if artifacts.exists():
        shutil.rmtree(artifacts)
    if (src / "artifacts").exists():
        shutil.copytree(src / "artifacts", artifacts)
    else:
        artifacts.mkdir()
    return manifest

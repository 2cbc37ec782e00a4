"""Trial files under ``<data_dir>/artifacts``: trajectories as .npz, written atomically."""

from __future__ import annotations

import base64
import binascii
import hashlib
import io
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db.models import Artifact, Trial
from app.service.auth import Actor
from app.service.errors import InvalidInput, NotFound, PayloadTooLarge


def decode_npz_b64(data_b64: str, *, max_bytes: int) -> bytes:
    """Base64 text → .npz bytes, checked to be a pickle-free NumPy archive."""
    if len(data_b64) > max_bytes * 4 // 3 + 8:
        raise PayloadTooLarge(f"trajectory is larger than {max_bytes} bytes")
    try:
        raw = base64.b64decode(data_b64, validate=True)
    except (binascii.Error, ValueError):
        raise InvalidInput("trajectory_npz_b64 is not valid base64") from None
    check_npz(raw)
    return raw


def check_npz(raw: bytes) -> dict[str, tuple[int, ...]]:
    """Names and shapes of the arrays in an .npz; InvalidInput if it is not one."""
    try:
        with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
            shapes = {k: tuple(npz[k].shape) for k in npz.files}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise InvalidInput(f"trajectory is not a NumPy .npz archive: {exc}") from None
    if not shapes:
        raise InvalidInput("trajectory .npz holds no arrays")
    return shapes


def store_trajectory(
    session: Session,
    artifacts_dir: Path,
    trial: Trial,
    raw: bytes,
    *,
    actor: Actor,
    tag: str,
) -> Artifact:
    """Write ``raw`` (.npz bytes) for ``trial`` (fsync + rename) and add its Artifact row."""
    rel = Path(f"experiment_{trial.experiment_id}") / f"trial_{trial.id}_{tag}.npz"
    path = artifacts_dir / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as f:
        f.write(raw)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    art = Artifact(
        trial_id=trial.id,
        kind="trajectory",
        path=rel.as_posix(),
        sha256=hashlib.sha256(raw).hexdigest(),
        size_bytes=len(raw),
        created_by=actor.username,
    )
    session.add(art)
    return art


def trajectory_path(session: Session, artifacts_dir: Path, trial_id: int) -> Path:
    """The newest trajectory file of a trial, or NotFound."""
    if session.get(Trial, trial_id) is None:
        raise NotFound(f"trial {trial_id} not found")
    art = session.scalar(
        select(Artifact)
        .where(Artifact.trial_id == trial_id, Artifact.kind == "trajectory")
        .order_by(Artifact.id.desc())
    )
    if art is None:
        raise NotFound(f"trial {trial_id} has no trajectory")
    path = artifacts_dir / art.path
    if not path.is_file():
        raise NotFound(f"trial {trial_id}'s trajectory file {art.path} is missing")
    return path


def npz_to_json(path_or_bytes: Path | bytes) -> dict[str, Any]:
    """Every array of an .npz as nested lists (NaN → None), keyed by its name."""
    src = io.BytesIO(path_or_bytes) if isinstance(path_or_bytes, bytes) else path_or_bytes
    out: dict[str, Any] = {}
    with np.load(src, allow_pickle=False) as npz:
        for k in npz.files:
            a = np.asarray(npz[k])
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                out[k] = np.where(np.isfinite(a), a.astype(object), np.full(a.shape, None)).tolist()
            else:
                out[k] = a.tolist()
    return out

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
from numpy.lib import format as npformat
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db.models import Artifact, Trial
from app.service.auth import Actor
from app.service.errors import InvalidInput, NotFound, PayloadTooLarge

# What a trajectory may hold (the arrays of ``app.sim.Trajectory`` or a tracker's stream):
# up to MAX_ARRAYS numeric arrays of 1-3 dimensions, each with at most MAX_SAMPLES samples
# (5 s at 10 kHz) along its first axis and MAX_SAMPLE_VALUES numbers per sample (qpos: 61),
# at most MAX_DECOMPRESSED_BYTES once unpacked. Checked from the .npy headers, before any
# array is unpacked, so a small zip of a huge array costs nothing.
MAX_ARRAYS = 32
MAX_SAMPLES = 50_000
MAX_SAMPLE_VALUES = 128
MAX_DECOMPRESSED_BYTES = 64 * 1024 * 1024
#: the most numbers ``?format=json`` turns into JSON lists; more is refused (use npz)
MAX_JSON_VALUES = 2_000_000


def decode_npz_b64(data_b64: str, *, max_bytes: int) -> bytes:
    """Base64 text → .npz bytes, checked to be a pickle-free NumPy archive within the limits.

    Pure CPU and memory bounded by the limits: call it before opening a write transaction."""
    if len(data_b64) > max_bytes * 4 // 3 + 8:
        raise PayloadTooLarge(f"trajectory is larger than {max_bytes} bytes")
    try:
        raw = base64.b64decode(data_b64, validate=True)
    except (binascii.Error, ValueError):
        raise InvalidInput("trajectory_npz_b64 is not valid base64") from None
    check_npz(raw)
    return raw


def _headers(src: Any) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """Each array's shape and dtype from its .npy header, without unpacking its data."""
    out: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
    with zipfile.ZipFile(src) as zf:
        members = zf.infolist()
        if len(members) > MAX_ARRAYS:
            raise PayloadTooLarge(f"trajectory holds {len(members)} arrays; at most {MAX_ARRAYS}")
        for info in members:
            name = info.filename.removesuffix(".npy")
            with zf.open(info) as f:
                version = npformat.read_magic(f)
                if version == (1, 0):
                    shape, _fortran, dtype = npformat.read_array_header_1_0(f)
                else:
                    shape, _fortran, dtype = npformat.read_array_header_2_0(f)
            out[name] = (tuple(int(n) for n in shape), dtype)
    return out


def check_npz(raw: bytes | Path) -> dict[str, tuple[int, ...]]:
    """Names and shapes of the arrays in an .npz; InvalidInput if it is not one, or holds a
    non-numeric array or one of a shape no trajectory has; PayloadTooLarge past the limits."""
    src = io.BytesIO(raw) if isinstance(raw, bytes) else raw
    try:
        headers = _headers(src)
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise InvalidInput(f"trajectory is not a NumPy .npz archive: {exc}") from None
    if not headers:
        raise InvalidInput("trajectory .npz holds no arrays")
    total = 0
    for name, (shape, dtype) in headers.items():
        if dtype.kind not in "biuf" or dtype.hasobject:
            raise InvalidInput(f"trajectory array {name!r} has dtype {dtype}; only numbers")
        if not 1 <= len(shape) <= 3:
            raise InvalidInput(
                f"trajectory array {name!r} has {len(shape)} dimensions; a trajectory's have "
                "1 to 3 (samples first)"
            )
        per_sample = int(np.prod(shape[1:], dtype=np.int64))
        if shape[0] > MAX_SAMPLES or per_sample > MAX_SAMPLE_VALUES:
            raise PayloadTooLarge(
                f"trajectory array {name!r} has shape {shape}; at most {MAX_SAMPLES} samples "
                f"of at most {MAX_SAMPLE_VALUES} numbers each"
            )
        total += shape[0] * per_sample * dtype.itemsize
    if total > MAX_DECOMPRESSED_BYTES:
        raise PayloadTooLarge(
            f"trajectory unpacks to {total} bytes; at most {MAX_DECOMPRESSED_BYTES}"
        )
    return {name: shape for name, (shape, _) in headers.items()}


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
    """Every array of an .npz as nested lists (NaN → None), keyed by its name.

    The headers are checked first (``check_npz``); more than ``MAX_JSON_VALUES`` numbers are
    refused (PayloadTooLarge: ask for the .npz, which is streamed from disk)."""
    shapes = check_npz(path_or_bytes)
    n_values = sum(int(np.prod(shape, dtype=np.int64)) for shape in shapes.values())
    if n_values > MAX_JSON_VALUES:
        raise PayloadTooLarge(
            f"the trajectory holds {n_values} numbers, too many for JSON (at most "
            f"{MAX_JSON_VALUES}); ask for ?format=npz"
        )
    src = io.BytesIO(path_or_bytes) if isinstance(path_or_bytes, bytes) else path_or_bytes
    out: dict[str, Any] = {}
    with np.load(src, allow_pickle=False) as npz:
        for k in npz.files:
            a = np.asarray(npz[k])
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                out[k] = np.where(np.isfinite(a), a, None).tolist()
            else:
                out[k] = a.tolist()
    return out

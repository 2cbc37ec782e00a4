"""An experiment as one JSON bundle, and back: everything, for archiving or moving it.

``export_bundle`` carries every column of the experiment, its trials, raw measurements (who,
when, unit, note, source; withdrawn and superseded ones too), previews, sim twins, confirmations,
artifacts (the trajectory files themselves, base64) and its audit log. ``import_bundle``
stores it as a new experiment (new ids, every reference mapped, corrections to the repeats
they correct, files written, their SHA-256 checked) plus one audit row saying so; its link
to a sim prior (another experiment) is not carried over.
Exporting the import again gives the same bundle but for ids, file paths and that audit
row (tested).
Leases and idempotency keys are operational state, not the experiment's record: left out.
"""

from __future__ import annotations

import base64
import hashlib
from datetime import datetime
from pathlib import Path
from typing import Any

from sqlalchemy import Table, insert, select, update
from sqlalchemy.orm import Session

from app.db.base import UTCDateTime
from app.db.models import (
    Artifact,
    AuditLog,
    Confirmation,
    Experiment,
    Measurement,
    Preview,
    Trial,
    TrialTwin,
)
from app.service.audit import json_safe, record
from app.service.auth import Actor
from app.service.errors import InvalidInput
from app.service.experiments import get_experiment

FORMAT = "handful-experiment-bundle"
VERSION = 1
_TABLE: dict[str, Table] = {
    "experiment": Experiment.__table__,
    "trials": Trial.__table__,
    "measurements": Measurement.__table__,
    "confirmations": Confirmation.__table__,
    "previews": Preview.__table__,
    "twins": TrialTwin.__table__,
    "artifacts": Artifact.__table__,
    "audit": AuditLog.__table__,
}


def _row(table: Table, values: Any) -> dict[str, Any]:
    out = {}
    for col in table.columns:
        v = values[col.name]
        out[col.name] = v.isoformat() if isinstance(v, datetime) else json_safe(v)
    return out


def _rows(session: Session, table: Table, where: Any) -> list[dict[str, Any]]:
    q = select(table).where(where).order_by(table.c.id)
    return [_row(table, r) for r in session.execute(q).mappings()]


def export_bundle(session: Session, experiment_id: int, artifacts_dir: Path) -> dict[str, Any]:
    """The experiment and everything recorded about it (see the module docstring)."""
    get_experiment(session, experiment_id)  # NotFound
    exp_t, trials_t = _TABLE["experiment"], _TABLE["trials"]
    [experiment] = _rows(session, exp_t, exp_t.c.id == experiment_id)
    trials = _rows(session, trials_t, trials_t.c.experiment_id == experiment_id)
    ids = [t["id"] for t in trials]
    bundle: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "experiment": experiment,
        "trials": trials,
    }
    for name in ("measurements", "confirmations", "previews", "twins", "artifacts"):
        table = _TABLE[name]
        bundle[name] = _rows(session, table, table.c.trial_id.in_(ids)) if ids else []
    for art in bundle["artifacts"]:
        path = artifacts_dir / art["path"]
        art["content_b64"] = (
            base64.b64encode(path.read_bytes()).decode() if path.is_file() else None
        )
    audit = _TABLE["audit"]
    bundle["audit"] = _rows(session, audit, audit.c.experiment_id == experiment_id)
    return bundle


def _insert(session: Session, table: Table, values: dict[str, Any]) -> int:
    """INSERT one row; its new primary key."""
    result = session.execute(insert(table).values(**values))
    return int(result.inserted_primary_key[0])  # type: ignore[attr-defined]


def _values(table: Table, row: dict[str, Any], **override: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for col in table.columns:
        if col.name == "id" or col.name not in row:
            continue
        v = row[col.name]
        if v is not None and isinstance(col.type, UTCDateTime):
            v = datetime.fromisoformat(v)
        out[col.name] = v
    out.update(override)
    return out


def import_bundle(
    session: Session, bundle: dict[str, Any], artifacts_dir: Path, *, actor: Actor
) -> int:
    """Store a bundle as a new experiment; returns its id (flushed; ``Database.write``
    commits). InvalidInput for a bundle that is not one, or whose files do not match."""
    if bundle.get("format") != FORMAT or bundle.get("version") != VERSION:
        raise InvalidInput(f"not a {FORMAT} version {VERSION}")
    try:
        exp_row = bundle["experiment"]
        optional = ("previews", "twins")  # bundles from before previews / sim twins
        tables = {name: bundle[name] for name in _TABLE if name not in ("experiment", *optional)}
        for name in optional:
            tables[name] = bundle.get(name, [])
    except KeyError as exc:
        raise InvalidInput(f"the bundle lacks {exc}") from None
    exp_t = _TABLE["experiment"]
    # its sim prior is another experiment, not in the bundle: the copy starts unlinked
    exp_id = _insert(session, exp_t, _values(exp_t, exp_row, sim_prior_experiment_id=None))
    trial_map: dict[int, int] = {}
    trials_t = _TABLE["trials"]
    for t in tables["trials"]:
        trial_map[int(t["id"])] = _insert(
            session, trials_t, _values(trials_t, t, experiment_id=exp_id)
        )

    if exp_row.get("reference_trial_id") is not None:  # the drift check's trial, renumbered
        session.execute(
            update(exp_t)
            .where(exp_t.c.id == exp_id)
            .values(reference_trial_id=trial_map.get(int(exp_row["reference_trial_id"])))
        )

    def trial_of(row: dict[str, Any]) -> int:
        try:
            return trial_map[int(row["trial_id"])]
        except (KeyError, TypeError, ValueError):
            raise InvalidInput(
                f"a row refers to trial {row.get('trial_id')}, not in the bundle"
            ) from None

    measurement_map: dict[int, int] = {}
    meas_t = _TABLE["measurements"]
    for row in sorted(tables["measurements"], key=lambda r: int(r["id"])):
        old = row.get("supersedes_id")
        if old is not None and int(old) not in measurement_map:
            raise InvalidInput(f"measurement {row['id']} corrects {old}, not in the bundle")
        measurement_map[int(row["id"])] = _insert(
            session,
            meas_t,
            _values(
                meas_t,
                row,
                trial_id=trial_of(row),
                supersedes_id=None if old is None else measurement_map[int(old)],
            ),
        )
    for name in ("confirmations", "previews", "twins"):
        table = _TABLE[name]
        for row in tables[name]:
            session.execute(insert(table).values(**_values(table, row, trial_id=trial_of(row))))
    art_t = _TABLE["artifacts"]
    for row in tables["artifacts"]:
        tid = trial_of(row)
        raw = base64.b64decode(row.get("content_b64") or "")
        if hashlib.sha256(raw).hexdigest() != row["sha256"]:
            raise InvalidInput(f"artifact {row['path']}: its content does not match its SHA-256")
        rel = Path(f"experiment_{exp_id}") / f"trial_{tid}_{Path(row['path']).name}"
        path = artifacts_dir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(raw)
        session.execute(
            insert(art_t).values(**_values(art_t, row, trial_id=tid, path=rel.as_posix()))
        )
    audit_t = _TABLE["audit"]
    for row in tables["audit"]:
        old_trial = row.get("trial_id")
        entity_id = row["entity_id"]
        if row["entity"] == "experiment":
            entity_id = str(exp_id)
        elif row["entity"] == "trial" and entity_id.isdigit():
            entity_id = str(trial_map.get(int(entity_id), entity_id))
        elif row["entity"] == "measurement" and entity_id.isdigit():
            entity_id = str(measurement_map.get(int(entity_id), entity_id))
        session.execute(
            insert(audit_t).values(
                **_values(
                    audit_t,
                    row,
                    experiment_id=exp_id,
                    trial_id=None if old_trial is None else trial_map.get(int(old_trial)),
                    entity_id=entity_id,
                )
            )
        )
    record(
        session,
        actor=actor.username,
        action="experiment.import_bundle",
        entity="experiment",
        entity_id=exp_id,
        experiment_id=exp_id,
        detail={"from_experiment_id": exp_row.get("id"), "trials": len(trial_map)},
    )
    session.flush()
    return exp_id

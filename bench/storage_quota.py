"""What per-owner storage quotas (issue 58, ``AD_OWNER_STORAGE_BYTES``) cost an upload's
record and a lease, with few and with many artifacts stored.

In process, on a migrated SQLite file (or ``--database-url``): ``--studies`` managed
studies of ``--owners`` owners, and ``--artifacts`` artifacts spread over the first
owner's trials, written straight into the database. Then, in the same run, each arm
alternating with the others:

- upload: one write transaction that checks an upload's room and records it
  (``artifact_room`` + ``record_artifact``, a re-upload of one name, its size changing),
  with the quota checked (``owner_bytes`` set) and without; and with the totals'
  triggers dropped (what recording cost before migration 0015);
- lease: a lease of a queued trial and its release (``lease_queued_trial`` and
  ``release_lease``, one write each), with a quota that one owner (the one with the
  artifacts) is past and with none.

Each figure is the median CPU microseconds per operation over ``--rounds`` rounds of
``--ops`` operations.

    python bench/storage_quota.py [--artifacts 100000] [--studies 200] [--owners 20]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import sqlalchemy as sa

from adclient.testing.figures import emit
from adservice.db import Database, upgrade_to_head
from adservice.models import ArtifactRow, StudyRow, TrialRow, utcnow
from adservice.principals import OPEN_ADMIN
from adservice.repository import artifacts as artifact_repo
from adservice.repository import leases as lease_repo

TRIGGERS = (
    "storage_of_artifact_insert",
    "storage_of_artifact_update",
    "storage_of_artifact_delete",
)


def populate(db: Database, *, studies: int, owners: int, artifacts: int) -> tuple[int, int]:
    """The studies, their trials and the artifacts; returns (a running trial of the first
    owner, held by worker "w"; a study of another owner with a queued trial)."""
    now = utcnow()
    box = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
    with db.write() as session:
        rows = [
            StudyRow(
                name=f"s{i}",
                direction="maximize",
                space=box,
                proposer={"name": "random"},
                task={"name": "noop", "external": True},
                max_trials=10**6,
                owner_token_id=1 + i % owners,
            )
            for i in range(studies)
        ]
        session.add_all(rows)
        session.flush()
        first, other = rows[0].id, rows[1].id
        per_trial = 30
        trials = max(1, artifacts // per_trial)
        session.execute(
            sa.insert(TrialRow),
            [
                {
                    "study_id": first,
                    "number": n,
                    "state": "complete",
                    "vector": [0.5],
                    "params": {"x": 0.5},
                    "metrics": {},
                    "info": {},
                    "created_at": now,
                }
                for n in range(trials)
            ],
        )
        running = TrialRow(
            study_id=first,
            number=trials,
            state="running",
            vector=[0.5],
            params={"x": 0.5},
            metrics={},
            info={},
            worker_id="w",
            attempts=1,
            leases=1,
            lease_expires_at=utcnow().replace(year=2100),
        )
        queued = TrialRow(study_id=other, number=0, state="queued", vector=[0.5], params={"x": 0.5})
        session.add_all([running, queued])
        session.flush()
        ids = list(session.scalars(sa.select(TrialRow.id).where(TrialRow.study_id == first)))
        session.execute(
            sa.insert(ArtifactRow) if artifacts else sa.select(1),
            [
                {
                    "trial_id": ids[i % trials],
                    "name": f"a{i // trials}",
                    "content_type": "application/octet-stream",
                    "size": 1000,
                    "sha256": "",
                    "path": "",
                    "created_at": now,
                }
                for i in range(artifacts)
            ]
            or None,
        )
        return running.id, other


def per_op(operation: Callable[[int], None], ops: int) -> float:
    started = time.process_time()
    for index in range(ops):
        operation(index)
    return (time.process_time() - started) / ops * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--database-url", default=None)
    parser.add_argument("--artifacts", type=int, default=100_000)
    parser.add_argument("--studies", type=int, default=200)
    parser.add_argument("--owners", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--ops", type=int, default=200)
    args = parser.parse_args()
    url = args.database_url or f"sqlite:///{Path(tempfile.mkdtemp()) / 'quota.db'}"
    upgrade_to_head(url)
    db = Database(url)
    trial_id, _other = populate(
        db, studies=args.studies, owners=args.owners, artifacts=args.artifacts
    )
    quota = 10**15
    with db.read() as session:
        used = session.scalar(sa.text("SELECT bytes FROM owner_storage WHERE owner_key = 1"))
    past = max(int(used), 1)  # the first owner is at this quota: its studies are skipped

    def upload(owner_bytes: int | None) -> Callable[[int], None]:
        limits = artifact_repo.ArtifactQuota(
            count=10**6, total_bytes=10**15, artifact_bytes=10**9, owner_bytes=owner_bytes
        )

        def one(index: int) -> None:
            with db.write() as session:
                artifact_repo.artifact_room(
                    session,
                    trial_id=trial_id,
                    name="x",
                    worker_id="w",
                    caller=OPEN_ADMIN,
                    quota=limits,
                )
                artifact_repo.record_artifact(
                    session,
                    trial_id=trial_id,
                    name="x",
                    content_type="application/octet-stream",
                    size=100 + index % 2,
                    sha256="",
                    path=f"p{index}",
                    worker_id="w",
                    caller=OPEN_ADMIN,
                    quota=limits,
                )

        return one

    def lease(storage_quota: int | None) -> Callable[[int], None]:
        def one(_index: int) -> None:
            with db.write() as session:
                row = lease_repo.lease_queued_trial(
                    session,
                    worker_id="v",
                    lease_token_id=None,
                    lease_seconds=60,
                    storage_quota=storage_quota,
                )
                assert row is not None and (row.study_id != 1 or not args.artifacts)
                leased = row.id
            with db.write() as session:
                lease_repo.release_lease(session, trial_id=leased, worker_id="v", caller=OPEN_ADMIN)

        return one

    arms: dict[str, Callable[[int], None]] = {
        "upload_us_quota": upload(quota),
        "upload_us_no_quota": upload(None),
        "lease_us_quota": lease(past),
        "lease_us_no_quota": lease(None),
    }
    figures: dict[str, list[float]] = {name: [] for name in [*arms, "upload_us_no_triggers"]}
    for _ in range(args.rounds):
        for name, operation in arms.items():
            figures[name].append(per_op(operation, args.ops))
    if db.dialect == "sqlite":  # last: the triggers do not come back
        with db.write() as session:
            for trigger in TRIGGERS:
                session.execute(sa.text(f"DROP TRIGGER {trigger}"))
        for _ in range(args.rounds):
            figures["upload_us_no_triggers"].append(per_op(upload(None), args.ops))
    db.dispose()
    print(f"{args.artifacts} artifacts, {args.studies} studies of {args.owners} owners")
    for name, values in figures.items():
        if values:
            emit(name, statistics.median(values), higher_is_better=False, unit="us CPU")


if __name__ == "__main__":
    main()

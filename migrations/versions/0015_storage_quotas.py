"""Issue 58 (bound every cost a user controls): the bytes each study and each owner
stores, artifacts and template URDFs, as running totals the database keeps itself.

``study_storage`` holds a study's artifact and URDF bytes, ``owner_storage`` the sum over
an owner's studies (``owner_key``: the owning token's id, 0 for studies without an
owner). Triggers keep both exact in the transaction that adds or removes the bytes,
whatever code writes the rows: a new study gets its row, an artifact's size and a stored
URDF's bytes are added to its study's row, and a study's row passes each change on to
its owner's (a deleted study, whose row goes with it, takes its bytes off). Existing rows
are counted here.

A later migration that recreates ``studies``, ``artifacts``, ``trial_urdfs`` or
``study_storage`` on SQLite (a batch "move and copy") drops their triggers: it must make
them again (``create_triggers``); tests/service/test_storage_quotas.py checks they exist
at head.

Revision ID: 0015
Revises: 0014
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0015"
down_revision = "0014"
branch_labels = None
depends_on = None

TRIGGERS = (
    ("studies", "storage_of_new_study", "AFTER INSERT"),
    ("study_storage", "storage_to_owner", "AFTER INSERT OR UPDATE OR DELETE"),
    ("artifacts", "storage_of_artifacts", "AFTER INSERT OR UPDATE OF size OR DELETE"),
    ("trial_urdfs", "storage_of_urdfs", "AFTER INSERT OR DELETE"),
)
"""(table, trigger, when) on PostgreSQL, one function of the trigger's name each."""


def _sqlite_triggers() -> list[str]:
    study_of = "(SELECT study_id FROM trials WHERE id = {row}.trial_id)"
    urdf = (
        "coalesce(length(CAST({row}.urdf AS BLOB)), 0)"
        " + coalesce(length(CAST({row}.error AS BLOB)), 0)"
    )

    def add(name: str, when: str, column: str, amount: str, row: str) -> str:
        return (
            f"CREATE TRIGGER {name} {when} BEGIN UPDATE study_storage "
            f"SET {column} = {column} + ({amount}) WHERE study_id = {study_of.format(row=row)}; END"
        )

    return [
        "CREATE TRIGGER storage_of_new_study AFTER INSERT ON studies BEGIN "
        "INSERT INTO study_storage (study_id, owner_key, artifact_bytes, urdf_bytes) "
        "VALUES (NEW.id, coalesce(NEW.owner_token_id, 0), 0, 0); END",
        "CREATE TRIGGER storage_to_owner_insert AFTER INSERT ON study_storage BEGIN "
        "INSERT INTO owner_storage (owner_key, bytes) "
        "VALUES (NEW.owner_key, NEW.artifact_bytes + NEW.urdf_bytes) "
        "ON CONFLICT (owner_key) DO UPDATE SET bytes = bytes + excluded.bytes; END",
        "CREATE TRIGGER storage_to_owner_update AFTER UPDATE ON study_storage BEGIN "
        "UPDATE owner_storage SET bytes = bytes + (NEW.artifact_bytes + NEW.urdf_bytes) "
        "- (OLD.artifact_bytes + OLD.urdf_bytes) WHERE owner_key = NEW.owner_key; END",
        "CREATE TRIGGER storage_to_owner_delete AFTER DELETE ON study_storage BEGIN "
        "UPDATE owner_storage SET bytes = bytes - (OLD.artifact_bytes + OLD.urdf_bytes) "
        "WHERE owner_key = OLD.owner_key; END",
        add(
            "storage_of_artifact_insert",
            "AFTER INSERT ON artifacts",
            "artifact_bytes",
            "NEW.size",
            "NEW",
        ),
        add(
            "storage_of_artifact_update",
            "AFTER UPDATE OF size ON artifacts",
            "artifact_bytes",
            "NEW.size - OLD.size",
            "NEW",
        ),
        add(
            "storage_of_artifact_delete",
            "AFTER DELETE ON artifacts",
            "artifact_bytes",
            "-OLD.size",
            "OLD",
        ),
        add(
            "storage_of_urdf_insert",
            "AFTER INSERT ON trial_urdfs",
            "urdf_bytes",
            urdf.format(row="NEW"),
            "NEW",
        ),
        add(
            "storage_of_urdf_delete",
            "AFTER DELETE ON trial_urdfs",
            "urdf_bytes",
            f"-({urdf.format(row='OLD')})",
            "OLD",
        ),
    ]


SQLITE_TRIGGER_NAMES = (
    "storage_of_new_study",
    "storage_to_owner_insert",
    "storage_to_owner_update",
    "storage_to_owner_delete",
    "storage_of_artifact_insert",
    "storage_of_artifact_update",
    "storage_of_artifact_delete",
    "storage_of_urdf_insert",
    "storage_of_urdf_delete",
)

_POSTGRES_FUNCTIONS = {
    "storage_of_new_study": """
        INSERT INTO study_storage (study_id, owner_key, artifact_bytes, urdf_bytes)
        VALUES (NEW.id, coalesce(NEW.owner_token_id, 0), 0, 0);
        RETURN NULL;""",
    "storage_to_owner": """
        IF TG_OP = 'INSERT' THEN
            INSERT INTO owner_storage (owner_key, bytes)
            VALUES (NEW.owner_key, NEW.artifact_bytes + NEW.urdf_bytes)
            ON CONFLICT (owner_key) DO UPDATE SET bytes = owner_storage.bytes + excluded.bytes;
        ELSIF TG_OP = 'UPDATE' THEN
            UPDATE owner_storage SET bytes = bytes + (NEW.artifact_bytes + NEW.urdf_bytes)
                - (OLD.artifact_bytes + OLD.urdf_bytes)
            WHERE owner_key = NEW.owner_key;
        ELSE
            UPDATE owner_storage SET bytes = bytes - (OLD.artifact_bytes + OLD.urdf_bytes)
            WHERE owner_key = OLD.owner_key;
        END IF;
        RETURN NULL;""",
    "storage_of_artifacts": """
        IF TG_OP = 'INSERT' THEN
            UPDATE study_storage SET artifact_bytes = artifact_bytes + NEW.size
            WHERE study_id = (SELECT study_id FROM trials WHERE id = NEW.trial_id);
        ELSIF TG_OP = 'UPDATE' THEN
            UPDATE study_storage SET artifact_bytes = artifact_bytes + NEW.size - OLD.size
            WHERE study_id = (SELECT study_id FROM trials WHERE id = NEW.trial_id);
        ELSE
            UPDATE study_storage SET artifact_bytes = artifact_bytes - OLD.size
            WHERE study_id = (SELECT study_id FROM trials WHERE id = OLD.trial_id);
        END IF;
        RETURN NULL;""",
    "storage_of_urdfs": """
        IF TG_OP = 'INSERT' THEN
            UPDATE study_storage SET urdf_bytes = urdf_bytes
                + coalesce(octet_length(NEW.urdf), 0) + coalesce(octet_length(NEW.error), 0)
            WHERE study_id = (SELECT study_id FROM trials WHERE id = NEW.trial_id);
        ELSE
            UPDATE study_storage SET urdf_bytes = urdf_bytes
                - coalesce(octet_length(OLD.urdf), 0) - coalesce(octet_length(OLD.error), 0)
            WHERE study_id = (SELECT study_id FROM trials WHERE id = OLD.trial_id);
        END IF;
        RETURN NULL;""",
}


def create_triggers() -> None:
    """The triggers that keep ``study_storage`` and ``owner_storage`` (for a migration
    that had to recreate one of their tables)."""
    if op.get_bind().dialect.name == "postgresql":
        for table, name, when in TRIGGERS:
            op.execute(
                f"CREATE FUNCTION {name}() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN"
                f"{_POSTGRES_FUNCTIONS[name]}\nEND $$"
            )
            op.execute(
                f"CREATE TRIGGER {name} {when} ON {table} FOR EACH ROW EXECUTE FUNCTION {name}()"
            )
    else:
        for statement in _sqlite_triggers():
            op.execute(statement)


def drop_triggers() -> None:
    if op.get_bind().dialect.name == "postgresql":
        for table, name, _ in TRIGGERS:
            op.execute(f"DROP TRIGGER IF EXISTS {name} ON {table}")
            op.execute(f"DROP FUNCTION IF EXISTS {name}()")
    else:
        for name in SQLITE_TRIGGER_NAMES:
            op.execute(f"DROP TRIGGER IF EXISTS {name}")


def upgrade() -> None:
    op.create_table(
        "owner_storage",
        sa.Column("owner_key", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("bytes", sa.BigInteger(), nullable=False),
        sa.PrimaryKeyConstraint("owner_key"),
    )
    op.create_table(
        "study_storage",
        sa.Column("study_id", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("owner_key", sa.Integer(), nullable=False),
        sa.Column("artifact_bytes", sa.BigInteger(), nullable=False),
        sa.Column("urdf_bytes", sa.BigInteger(), nullable=False),
        sa.ForeignKeyConstraint(["study_id"], ["studies.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("study_id"),
    )
    create_triggers()
    postgres = op.get_bind().dialect.name == "postgresql"
    size = "octet_length({})" if postgres else "length(CAST({} AS BLOB))"
    urdf_bytes = f"coalesce({size.format('u.urdf')}, 0) + coalesce({size.format('u.error')}, 0)"
    # The new study_storage rows pass their bytes on to owner_storage (storage_to_owner).
    op.execute(
        sa.text(
            "INSERT INTO study_storage (study_id, owner_key, artifact_bytes, urdf_bytes) "
            "SELECT s.id, coalesce(s.owner_token_id, 0), "
            "(SELECT coalesce(sum(a.size), 0) FROM artifacts a JOIN trials t "
            "ON t.id = a.trial_id WHERE t.study_id = s.id), "
            f"(SELECT coalesce(sum({urdf_bytes}), 0) FROM trial_urdfs u JOIN trials t "
            "ON t.id = u.trial_id WHERE t.study_id = s.id) "
            "FROM studies s"
        )
    )


def downgrade() -> None:
    drop_triggers()
    op.drop_table("study_storage")
    op.drop_table("owner_storage")

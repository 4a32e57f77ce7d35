"""Engine, transactions and migrations: the one place that commits or rolls back.

SQLite runs in WAL mode; a write transaction takes the write lock up front
(``BEGIN IMMEDIATE``) and, inside one server process, writers queue on a lock
instead of spinning on "database is locked", on the one connection the process writes
through. PostgreSQL needs neither.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import sqlalchemy as sa
from sqlalchemy.engine import Engine
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

T = TypeVar("T")
log = logging.getLogger(__name__)


def _migrations_dir() -> Path:
    """The Alembic scripts: ``adservice/migrations`` in an installed wheel (setup.py copies
    them there), else ``migrations/`` at the top of the source tree (an editable install)."""
    package = Path(__file__).resolve().parent
    packaged = package / "migrations"
    return packaged if (packaged / "env.py").is_file() else package.parents[1] / "migrations"


MIGRATIONS_DIR = _migrations_dir()


def is_sqlite(engine: Engine) -> bool:
    return engine.dialect.name == "sqlite"


def make_engine(url: str) -> Engine:
    if not url.startswith("sqlite"):
        return sa.create_engine(url, pool_size=20, max_overflow=20, pool_pre_ping=True)
    engine = sa.create_engine(
        url,
        connect_args={"check_same_thread": False, "timeout": 30},
        pool_size=32,
        max_overflow=16,
    )

    @sa.event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: Any, _record: Any) -> None:
        # The transaction scope emits BEGIN itself (pysqlite's own is deferred-only).
        dbapi_connection.isolation_level = None
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA synchronous=NORMAL")  # durable across process crashes in WAL
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute("PRAGMA busy_timeout=30000")
        cursor.close()

    return engine


class Database:
    """Hands out read and write transactions on one engine."""

    def __init__(self, url: str, *, driver_statements: bool | None = None) -> None:
        """``driver_statements``: run ``Prepared`` statements on the driver (the default
        on SQLite; False runs them through SQLAlchemy, to compare the two)."""
        self.url = url
        self.engine = make_engine(url)
        sqlite = is_sqlite(self.engine)
        if driver_statements and not sqlite:
            raise ValueError("driver statements are compiled for SQLite only")
        self._driver_statements = sqlite if driver_statements is None else driver_statements
        self._write_lock = threading.Lock() if sqlite else None
        self._begin_read = "BEGIN" if sqlite else None
        self._begin_write = "BEGIN IMMEDIATE" if sqlite else None
        self._writer: sa.Connection | None = None
        """SQLite: the connection every write goes through, used under ``_write_lock``
        (writes take turns anyway): no pool check-out, check-in and reset per write."""

    @property
    def dialect(self) -> str:
        return self.engine.dialect.name

    @contextmanager
    def read(self) -> Iterator[Session]:
        with (
            self.engine.connect() as connection,
            _transaction(connection, self._begin_read, self._driver_statements) as session,
        ):
            yield session

    @contextmanager
    def write(self) -> Iterator[Session]:
        """A write transaction that commits on success and rolls back on any exception:
        every write of the service goes through here."""
        if self._write_lock is None:
            with (
                self.engine.connect() as connection,
                _transaction(connection, None, False) as session,
            ):
                yield session
            return
        with self._write_lock:
            if self._writer is None:
                self._writer = self.engine.connect()
            try:
                with _transaction(
                    self._writer, self._begin_write, self._driver_statements
                ) as session:
                    yield session
            finally:
                if self._writer.invalidated:
                    self._writer.close()
                    self._writer = None

    @property
    def writes_inline(self) -> bool:
        """Whether a short write may run on the event loop itself: on SQLite writes take
        turns on one lock anyway, and a hop to the thread pool costs more than the write;
        elsewhere a write can wait on another transaction's row lock, so it must not
        hold up the loop."""
        return self._write_lock is not None

    async def run(self, work: Callable[[], T]) -> T:
        """``work`` (short, database-bound) on the loop where writes run inline, else in
        the thread pool."""
        if self.writes_inline:
            return work()
        return await run_in_threadpool(work)

    def dispose(self) -> None:
        if self._write_lock is not None:
            with self._write_lock:
                if self._writer is not None:
                    self._writer.close()
                    self._writer = None
        self.engine.dispose()


_CONNECTION = "ad_connection"
_DRIVER = "ad_driver_statements"


def scope_connection(session: Session) -> sa.Connection:
    """The connection of the scope ``session`` belongs to, in the scope's transaction: for
    prebuilt Core statements, without the session's own transaction bookkeeping (which
    cost a fifth of a tell's database time, cProfile)."""
    connection: sa.Connection = session.info[_CONNECTION]
    return connection


class Prepared:
    """A hot Core statement (ask and tell run a few on every request), run in the
    transaction of the scope a session belongs to.

    On SQLite it runs on the scope's driver connection, compiled once per set of
    parameter names, exactly as SQLAlchemy would compile it, with the same type
    processing both ways: SQLAlchemy's execution around a statement cost about five
    times the statement itself there (cProfile of ask/tell cycles). Elsewhere it goes
    through SQLAlchemy."""

    def __init__(self, statement: sa.Insert | sa.Update) -> None:
        self.statement = statement
        self._compiled: dict[tuple[str, ...], _DriverStatement] = {}

    def rows(self, session: Session, params: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
        """Run once per parameter set (same names in each); the RETURNING rows, in order."""
        connection = scope_connection(session)
        if not session.info[_DRIVER]:
            result = connection.execute(self.statement, list(params))
            return [dict(row._mapping) for row in result] if result.returns_rows else []
        driver = self._driver(connection, tuple(params[0]))
        cursor = connection.connection.driver_connection.cursor()  # type: ignore[union-attr]
        try:
            return [row for values in params for row in driver.run(cursor, values)]
        finally:
            cursor.close()

    def row(self, session: Session, params: dict[str, Any]) -> dict[str, Any] | None:
        """The one RETURNING row of a single execution, or None when no row matched."""
        rows = self.rows(session, [params])
        return rows[0] if rows else None

    def _driver(self, connection: sa.Connection, names: tuple[str, ...]) -> _DriverStatement:
        compiled = self._compiled.get(names)
        if compiled is None:
            compiled = _DriverStatement(self.statement, connection.dialect, names)
            self._compiled[names] = compiled
        return compiled


class _DriverStatement:
    """One compilation of a statement for a positional (qmark) driver: its SQL, where each
    parameter comes from (the caller's, by name, or a literal's own value) with its bind
    processor, and the RETURNING columns' result processors."""

    def __init__(self, statement: sa.Insert | sa.Update, dialect: Any, names: Sequence[str]):
        compiled = statement.compile(dialect=dialect, column_keys=list(names))
        if compiled.positiontup is None:
            raise TypeError(f"{dialect.name} does not take positional parameters")
        self.sql = compiled.string
        self.binds: list[tuple[str | None, Any, Callable[[Any], Any] | None]] = []
        for name in compiled.positiontup:
            bind = compiled.binds[name]
            if bind.expanding:
                raise TypeError(f"{name!r} expands per execution: write IN as ORs here")
            processor = bind.type.dialect_impl(dialect).bind_processor(dialect)
            self.binds.append((name if name in names else None, bind.effective_value, processor))
        self.columns = [
            (str(column.key), column.type.dialect_impl(dialect).result_processor(dialect, None))
            for column in statement.exported_columns
        ]

    def run(self, cursor: Any, params: dict[str, Any]) -> list[dict[str, Any]]:
        values = []
        for name, literal, processor in self.binds:
            value = params[name] if name is not None else literal
            values.append(processor(value) if processor is not None else value)
        cursor.execute(self.sql, values)
        if not self.columns:
            return []
        return [
            {
                key: processor(value) if processor is not None else value
                for (key, processor), value in zip(self.columns, row, strict=True)
            }
            for row in cursor.fetchall()
        ]


@contextmanager
def _transaction(
    connection: sa.Connection, begin: str | None, driver_statements: bool
) -> Iterator[Session]:
    """A session on a connection whose transaction this scope owns: the session flushes
    into it, the connection commits (or rolls back) it. Measured: a session that runs its
    own transaction costs about 0.1 ms more per write, a tenth of a tell on the hot path.

    ``begin``: on SQLite, the statement that opens the transaction, sent straight to the
    driver (pysqlite's own BEGIN is deferred-only). SQLAlchemy's recipe sends it from a
    "begin" event instead; but any listener on the engine makes every statement dispatch
    its execution events, and through SQLAlchemy the BEGIN itself cost a fifth of a
    write's database time (cProfile, bench/throughput.py)."""
    with connection.begin():
        if begin is not None:
            connection.connection.driver_connection.execute(begin)  # type: ignore[union-attr]
        info = {_CONNECTION: connection, _DRIVER: driver_statements}
        session = Session(bind=connection, expire_on_commit=False, info=info)
        try:
            yield session
            session.flush()
        finally:
            session.close()


MIGRATION_LOCK = {"ns": 0x414D, "id": 0}  # "AM": apart from the per-study proposal locks


def upgrade_to_head(url: str) -> None:
    """Bring the schema to the newest Alembic revision (the server does this at start).

    A schema already at head is said in one line, with none of Alembic's own (its
    plugins and context, about 10 INFO lines a start); a migration logs each revision it
    runs, as Alembic does.

    On PostgreSQL an advisory lock makes processes that start at once (several servers,
    or a server and ``adserver token create``) migrate one after the other: otherwise
    both try to create the same tables and one fails."""
    with _alembic_quiet():  # importing alembic sets up its plugins, a line each
        from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    engine = sa.create_engine(url, poolclass=sa.NullPool)
    try:
        with engine.connect() as connection:
            if sa.make_url(url).get_backend_name() != "postgresql":
                _upgrade_if_behind(config, connection)
                return
            connection.execute(sa.text("SELECT pg_advisory_lock(:ns, :id)"), MIGRATION_LOCK)
            connection.commit()
            try:
                _upgrade_if_behind(config, connection)
            finally:
                connection.execute(sa.text("SELECT pg_advisory_unlock(:ns, :id)"), MIGRATION_LOCK)
                connection.commit()
    finally:
        engine.dispose()


def _upgrade_if_behind(config: Any, connection: sa.Connection) -> None:
    """Run Alembic's upgrade only where the stored revisions are not the scripts' heads."""
    with _alembic_quiet():  # the migration context's INFO lines
        from alembic import command
        from alembic.runtime.migration import MigrationContext
        from alembic.script import ScriptDirectory

        heads = set(ScriptDirectory.from_config(config).get_heads())
        stored = set(MigrationContext.configure(connection).get_current_heads())
    connection.rollback()  # the check's transaction, before the upgrade's own connection
    if stored == heads:
        log.info("database schema at head (revision %s): nothing to migrate", _revisions(heads))
        return
    start = f"revision {_revisions(stored)}" if stored else "an empty database"
    log.info("migrating the database schema from %s to revision %s", start, _revisions(heads))
    command.upgrade(config, "head")


@contextmanager
def _alembic_quiet() -> Iterator[None]:
    """Alembic's INFO lines left out for the block."""
    alembic_log = logging.getLogger("alembic")
    level = alembic_log.level
    alembic_log.setLevel(logging.WARNING)
    try:
        yield
    finally:
        alembic_log.setLevel(level)


def _revisions(revisions: set[str]) -> str:
    return ", ".join(sorted(revisions))

"""A throwaway PostgreSQL cluster for tests and benchmarks: Debian's ``postgresql``
package (``make test`` installs it: tests/system_packages.py), a cluster in a temporary
folder owned by an unprivileged user, listening on a free loopback port, removed when
stopped.

    with PostgresCluster.start() as cluster:
        url = cluster.create_database()   # postgresql+psycopg://postgres@127.0.0.1:PORT/db_1
        template = cluster.create_template(migrate)   # once: a database others copy
        copy = cluster.create_database(template=template)
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import itertools
import os
import pwd
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import psycopg

from adclient.testing.servers import free_port

SUPERUSER = "postgres"
UNPRIVILEGED_USER = "nobody"  # initdb and postgres refuse to run as root
PREFIX = "activedesign-pg-"


class PostgresUnavailable(RuntimeError):
    """PostgreSQL is not installed (tests/system_packages.py installs it)."""


def postgres_bin_dir() -> Path | None:
    """The folder with ``initdb`` and ``postgres``: Debian keeps them off PATH, in
    /usr/lib/postgresql/VERSION/bin; the newest version wins."""
    on_path = shutil.which("initdb")
    if on_path and Path(on_path).resolve().with_name("postgres").exists():
        return Path(on_path).resolve().parent
    versions = sorted(
        glob.glob("/usr/lib/postgresql/*/bin/initdb"),
        key=lambda path: int(Path(path).parts[-3]) if Path(path).parts[-3].isdigit() else 0,
    )
    return Path(versions[-1]).parent if versions else None


def installed_bin_dir() -> Path:
    """The PostgreSQL bin folder. The tests never install it themselves: ``make test``
    does, once, before any test process starts."""
    found = postgres_bin_dir()
    if found is None:
        raise PostgresUnavailable("PostgreSQL (initdb) is not installed")
    return found


def remove_stale_clusters(older_than_s: float = 600.0) -> None:
    """Delete the folders of clusters whose server is gone (a test run that was killed
    leaves its folder behind). A folder younger than the limit is never touched: another
    test process may be setting it up, and initdb's bootstrap backend leaves a
    ``postmaster.pid`` naming a process that has already exited."""
    for folder in Path(tempfile.gettempdir()).glob(f"{PREFIX}*"):
        pid_file = folder / "data" / "postmaster.pid"
        try:
            if time.time() - folder.stat().st_mtime < older_than_s:
                continue
            if pid_file.exists():
                pid = int(pid_file.read_text().split()[0])
                try:
                    os.kill(pid, 0)
                    continue  # running
                except ProcessLookupError:
                    pass
        except (OSError, ValueError, IndexError):
            continue
        shutil.rmtree(folder, ignore_errors=True)


def _die_with_parent() -> None:
    """Runs in the child after it dropped privileges: SIGQUIT (PostgreSQL's immediate
    shutdown) when the process that started it dies, so a killed test run leaves no
    server behind."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGQUIT)  # PR_SET_PDEATHSIG


@dataclass
class PostgresCluster:
    """One running throwaway cluster; trust authentication on 127.0.0.1 only."""

    root: Path
    port: int
    process: subprocess.Popen[bytes]
    _names: Iterator[int] = field(default_factory=lambda: itertools.count(1))

    @classmethod
    def start(cls, *, durable: bool = True, max_connections: int = 300) -> PostgresCluster:
        """Create and start a cluster. ``durable=False`` turns off fsync and synchronous
        commit: what tests need (nothing survives the run anyway), not what a benchmark
        of a real deployment should measure."""
        bin_dir = installed_bin_dir()
        remove_stale_clusters()
        root = Path(tempfile.mkdtemp(prefix=PREFIX))
        as_user: dict[str, object] = {}
        if os.geteuid() == 0:
            account = pwd.getpwnam(UNPRIVILEGED_USER)
            os.chown(root, account.pw_uid, account.pw_gid)
            as_user = {"user": account.pw_uid, "group": account.pw_gid, "extra_groups": []}
        data = root / "data"
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LC_ALL": "C", "TZ": "UTC"}
        done = subprocess.run(
            [
                str(bin_dir / "initdb"),
                "-D",
                str(data),
                "-U",
                SUPERUSER,
                "--auth=trust",
                "--encoding=UTF8",
                "--locale=C",
                "--no-sync",
            ],
            cwd=root,
            env=env,
            capture_output=True,
            text=True,
            **as_user,  # type: ignore[call-overload]
        )
        if done.returncode != 0:
            shutil.rmtree(root, ignore_errors=True)
            raise RuntimeError(f"initdb failed:\n{done.stdout}\n{done.stderr}")
        settings = {
            "listen_addresses": "127.0.0.1",
            "unix_socket_directories": str(root),
            "max_connections": str(max_connections),
            "shared_buffers": "128MB",
        }
        if not durable:
            settings |= {"fsync": "off", "synchronous_commit": "off", "full_page_writes": "off"}
        last_error = ""
        for _attempt in range(5):  # another process may take the free port first
            port = free_port()
            options = [f"-c{key}={value}" for key, value in {**settings, "port": port}.items()]
            log = (root / "postgres.log").open("ab")
            process = subprocess.Popen(
                [str(bin_dir / "postgres"), "-D", str(data), *options],
                cwd=root,
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
                preexec_fn=_die_with_parent,
                **as_user,  # type: ignore[call-overload]
            )
            log.close()
            cluster = cls(root=root, port=port, process=process)
            if cluster._wait_ready():
                return cluster
            last_error = (root / "postgres.log").read_text(errors="replace")[-3000:]
            cluster._terminate()
        shutil.rmtree(root, ignore_errors=True)
        raise RuntimeError(f"PostgreSQL did not start:\n{last_error}")

    def _wait_ready(self, timeout: float = 60.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                return False
            try:
                with psycopg.connect(self.dsn("postgres"), connect_timeout=2):
                    return True
            except psycopg.OperationalError:
                time.sleep(0.1)
        return False

    def dsn(self, database: str) -> str:
        return f"host=127.0.0.1 port={self.port} user={SUPERUSER} dbname={database}"

    def url(self, database: str) -> str:
        """The SQLAlchemy URL of one database (psycopg 3)."""
        return f"postgresql+psycopg://{SUPERUSER}@127.0.0.1:{self.port}/{database}"

    def create_database(self, prefix: str = "db", *, template: str | None = None) -> str:
        """A new database, empty, or a copy of ``template`` (a URL from
        :meth:`create_template`); returns its SQLAlchemy URL."""
        name = f"{prefix}_{os.getpid()}_{next(self._names)}"
        copy = f' TEMPLATE "{template.rsplit("/", 1)[1]}"' if template is not None else ""
        with psycopg.connect(self.dsn("postgres"), autocommit=True) as connection:
            if connection.info.server_version >= 150000:
                # Copy the template's files: PostgreSQL 15's default (WAL_LOG) writes every
                # block of the copy, system catalogs included, to the WAL, about four
                # times the server CPU of a file copy and its two checkpoints (cheap
                # here: small databases, and no fsync in a test cluster).
                copy += " STRATEGY FILE_COPY"
            connection.execute(f'CREATE DATABASE "{name}"{copy}')  # names are ours: no user text
        return self.url(name)

    def create_template(self, prepare: Callable[[str], None]) -> str:
        """A database that ``prepare(url)`` fills (e.g. migrates), then closed to
        connections, so that :meth:`create_database` can copy it (PostgreSQL copies a
        template only while no one is connected to it); returns its URL."""
        url = self.create_database("template")
        prepare(url)
        name = url.rsplit("/", 1)[1]
        with psycopg.connect(self.dsn("postgres"), autocommit=True) as connection:
            connection.execute(f'ALTER DATABASE "{name}" WITH ALLOW_CONNECTIONS false')
        return url

    def drop_database(self, url: str) -> None:
        """Drop a database made by :meth:`create_database`, ending its connections."""
        name = url.rsplit("/", 1)[1]
        with psycopg.connect(self.dsn("postgres"), autocommit=True) as connection:
            connection.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')

    def _terminate(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)  # "fast" shutdown
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.process.send_signal(signal.SIGQUIT)
                self.process.wait()

    def stop(self) -> None:
        self._terminate()
        shutil.rmtree(self.root, ignore_errors=True)

    def __enter__(self) -> PostgresCluster:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()

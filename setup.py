"""Everything about the package is in pyproject.toml; this file adds one build step.

The Alembic migrations stay at the top of the source tree (``migrations/``, where
``alembic.ini`` and ``alembic`` find them), and a built wheel carries a copy of them inside
the server's package, ``adservice/migrations/``, where an installed ``adserver`` looks for
them (``adservice.db.MIGRATIONS_DIR``). An editable install copies nothing: there the server
finds ``migrations/`` beside its source. The sdist carries ``migrations/`` (MANIFEST.in), so
a wheel built from it gets the same copy.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

MIGRATIONS = Path(__file__).resolve().parent / "migrations"
PACKAGED = Path("adservice", "migrations")


class BuildPyWithMigrations(build_py):
    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return
        if not (MIGRATIONS / "env.py").is_file():
            raise FileNotFoundError(f"{MIGRATIONS}/env.py: the Alembic migrations are missing")
        target = Path(self.build_lib, PACKAGED)
        shutil.rmtree(target, ignore_errors=True)
        shutil.copytree(
            MIGRATIONS, target, ignore=shutil.ignore_patterns("__pycache__", "*.py[cod]")
        )


setup(cmdclass={"build_py": BuildPyWithMigrations})

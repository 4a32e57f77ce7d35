"""The built wheel and sdist, as a user gets them: ``pip install "activedesign[service]"``
from a wheel (never editable) must give an ``adserver`` that migrates its database and
serves the API, the dashboard and its vendored files.

The sdist is built from a copy of the source tree, the wheel from the sdist (what
``python -m build`` does), so a file the sdist forgets is missing from the wheel too. The
wheel is installed into a fresh virtual environment that sees, besides the standard
library, only the distributions the ``service`` extra needs (their closure, resolved from
the wheel's own metadata and linked from this environment): pip installs with
``--no-index``, so nothing is downloaded (torch included), and the server runs without
the worker's packages.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tarfile
import time
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path, PurePosixPath

import httpx
import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from adclient.testing.servers import free_port

pytestmark = pytest.mark.xdist_group("wheel")

REPO = Path(__file__).resolve().parents[1]
STATIC = REPO / "service" / "adservice" / "static"
HARNESS = REPO / "client" / "adclient" / "testing"
RECIPE = "vendor/three-urdf/"
"""static/vendor/three-urdf/ builds static/vendor/three-urdf.js: in the sdist, not the wheel."""
WORKER_ONLY = {"pybullet", "gymnasium", "stable-baselines3", "pillow"}


@dataclass(frozen=True)
class Built:
    wheel: Path
    sdist: Path


def source_files() -> list[str]:
    """What a build from this checkout sees: tracked files and untracked ones git does not
    ignore (a build ignores .venv, build/, caches; the copy does too)."""
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
        cwd=REPO,
        capture_output=True,
        check=True,
    ).stdout.decode()
    return [name for name in listed.split("\0") if name and (REPO / name).is_file()]


def clean_env(**extra: str) -> dict[str, str]:
    """This environment without pip's configuration and Python path settings: the fresh
    environment must stand on its own."""
    env = {
        key: value
        for key, value in os.environ.items()
        if not key.startswith(("PIP_", "PYTHON", "AD_")) and key != "VIRTUAL_ENV"
    }
    return {**env, "PIP_CONFIG_FILE": os.devnull, "PYTHONDONTWRITEBYTECODE": "1", **extra}


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Built:
    source = tmp_path_factory.mktemp("source")
    for name in source_files():
        target = source / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, target)
    # What `npm ci` leaves in the bundle's recipe folder must never ship.
    stray = source / "service/adservice/static" / RECIPE / "node_modules/three/build/three.js"
    stray.parent.mkdir(parents=True)
    stray.write_text("// npm's copy\n")
    dist = tmp_path_factory.mktemp("dist")
    done = subprocess.run(
        [sys.executable, "-m", "build", "--no-isolation", "--outdir", str(dist), str(source)],
        capture_output=True,
        text=True,
        env=clean_env(),
        timeout=300,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    (wheel,) = dist.glob("activedesign-*.whl")
    (sdist,) = dist.glob("activedesign-*.tar.gz")
    return Built(wheel=wheel, sdist=sdist)


def relative(root: Path) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file()} - {
        p.relative_to(root).as_posix() for p in root.rglob("__pycache__/*")
    }


def test_the_wheel_carries_the_migrations_and_every_served_static_file(built: Built) -> None:
    names = set(zipfile.ZipFile(built.wheel).namelist())
    migrations = {f"adservice/migrations/{name}" for name in relative(REPO / "migrations")}
    assert "adservice/migrations/env.py" in migrations
    assert migrations <= names, sorted(migrations - names)
    static = {
        f"adservice/static/{name}"
        for name in relative(STATIC)
        if not name.startswith(RECIPE) and "node_modules" not in name
    }
    assert "adservice/static/vendor/three-urdf.js" in static
    shipped = {name for name in names if name.startswith("adservice/static/")}
    assert shipped == static, (sorted(shipped - static), sorted(static - shipped))
    assert not [name for name in names if "node_modules" in name or RECIPE in name]
    # The source tree's top-level migrations/ is not installed as a package of its own,
    # nor are the tests or the benchmarks; the process harness they share is the SDK's.
    assert not [name for name in names if name.startswith(("migrations/", "tests/", "bench/"))]
    harness = {f"adclient/testing/{name}" for name in relative(HARNESS) if name.endswith(".py")}
    assert "adclient/testing/servers.py" in harness
    assert harness <= names, sorted(harness - names)


def test_the_sdist_keeps_migrations_at_the_top_and_the_bundle_recipe(built: Built) -> None:
    with tarfile.open(built.sdist) as archive:
        root = archive.getnames()[0].split("/")[0]
        names = {name.split("/", 1)[1] for name in archive.getnames() if "/" in name}
    for needed in ("setup.py", "MANIFEST.in", "pyproject.toml", "alembic.ini"):
        assert needed in names
    assert {f"migrations/{name}" for name in relative(REPO / "migrations")} <= names
    assert f"service/adservice/static/{RECIPE}package-lock.json" in names
    assert not [name for name in names if "node_modules" in name], root


def service_closure(wheel: Path) -> list[metadata.Distribution]:
    """The installed distributions that ``activedesign[service]`` needs, recursively, as
    the wheel's metadata declares them (markers evaluated here)."""
    with zipfile.ZipFile(wheel) as archive:
        (meta,) = [n for n in archive.namelist() if n.endswith(".dist-info/METADATA")]
        lines = archive.read(meta).decode().splitlines()
    pending = [
        Requirement(line.split(":", 1)[1].strip())
        for line in lines
        if line.startswith("Requires-Dist:")
    ]
    pending = [r for r in pending if r.marker is None or r.marker.evaluate({"extra": "service"})]
    found: dict[str, metadata.Distribution] = {}
    seen: set[tuple[str, str]] = set()
    while pending:
        requirement = pending.pop()
        name = canonicalize_name(requirement.name)
        extras = {""} | set(requirement.extras)
        if all((name, extra) in seen for extra in extras):
            continue
        seen.update((name, extra) for extra in extras)
        try:
            found[name] = found.get(name) or metadata.distribution(requirement.name)
        except metadata.PackageNotFoundError:
            pytest.fail(f"the service extra needs {requirement}, which is not installed here")
        for line in found[name].requires or []:
            needed = Requirement(line)
            if needed.marker is None or any(
                needed.marker.evaluate({"extra": extra}) for extra in extras
            ):
                pending.append(needed)
    return list(found.values())


def link_distributions(distributions: list[metadata.Distribution], folder: Path) -> None:
    """Each distribution's top-level files and folders (its RECORD), linked into ``folder``."""
    folder.mkdir()
    for distribution in distributions:
        files = distribution.files
        assert files is not None, f"{distribution.metadata['Name']} has no RECORD"
        tops = {PurePosixPath(str(f)).parts[0] for f in files} - {".."}
        for top in tops:
            link = folder / top
            if not link.exists() and not link.is_symlink():
                link.symlink_to(Path(str(distribution.locate_file(top))))


@pytest.fixture(scope="module")
def environment(built: Built, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh virtual environment with the wheel installed with its service extra."""
    root = tmp_path_factory.mktemp("installed")
    closure = service_closure(built.wheel)
    names = {canonicalize_name(d.metadata["Name"]) for d in closure}
    assert "torch" in names and not names & WORKER_ONLY, sorted(names)
    link_distributions(closure, root / "service-deps")
    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    (site,) = venv.glob("lib/python*/site-packages")
    (site / "service-deps.pth").write_text(f"{root / 'service-deps'}\n")
    pip = [sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python")]
    done = subprocess.run(
        [*pip, "install", "--no-index", "--no-cache-dir", f"{built.wheel}[service]"],
        capture_output=True,
        text=True,
        env=clean_env(),
        timeout=300,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return venv


def test_the_installed_package_is_the_wheel_with_its_migrations(environment: Path) -> None:
    done = subprocess.run(
        [
            str(environment / "bin" / "python"),
            "-c",
            "import adservice.db as db, adclient, sys; "
            "import adclient.testing.load, adclient.testing.postgres as harness; "
            "print(db.__file__); print(db.MIGRATIONS_DIR); print(adclient.__file__); "
            "print(harness.__file__)",
        ],
        capture_output=True,
        text=True,
        cwd=environment,
        env=clean_env(),
        check=True,
    )
    site = next(environment.glob("lib/python*/site-packages"))
    db_file, migrations, adclient_file, harness_file = map(Path, done.stdout.split())
    assert db_file.is_relative_to(site) and adclient_file.is_relative_to(site)
    assert harness_file.is_relative_to(site)  # the harness runs from the wheel's service extra
    assert migrations == site.resolve() / "adservice" / "migrations"


@pytest.fixture
def served(environment: Path, tmp_path: Path) -> Iterator[str]:
    """The wheel's ``adserver`` on a fresh SQLite file; the base URL."""
    port = free_port()
    database = f"sqlite:///{tmp_path / 'wheel.db'}"
    adserver = str(environment / "bin" / "adserver")
    env = clean_env(AD_ARTIFACT_DIR=str(tmp_path / "artifacts"))
    # An operator's first step, before any server ran: it migrates the empty database.
    token = subprocess.run(
        [adserver, "token", "create", "--role", "worker", "--database-url", database],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
        timeout=120,
    )
    assert token.returncode == 0, token.stderr
    assert token.stdout.strip().startswith("adt_")
    log = tmp_path / "adserver.log"
    with log.open("wb") as out:
        process = subprocess.Popen(
            [adserver, "--host", "127.0.0.1", "--port", str(port), "--database-url", database],
            cwd=tmp_path,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            assert process.poll() is None, f"adserver exited:\n{log.read_text()}"
            assert time.monotonic() < deadline, f"adserver did not answer:\n{log.read_text()}"
            try:
                if httpx.get(f"{url}/healthz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.2)
        yield url
    finally:
        process.terminate()
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@pytest.mark.slow
@pytest.mark.e2e
def test_the_wheels_adserver_runs_a_study_and_serves_the_dashboard(served: str) -> None:
    from adclient import Client

    client = Client(served)
    study = client.create_study(
        name="wheel",
        direction="minimize",
        space={"type": "box", "params": [{"name": "x", "low": -5, "high": 5}]},
    )
    for _ in range(3):
        trial = study.ask()
        study.tell(trial, (trial.params["x"] - 1.0) ** 2)
    best = study.best_trial
    assert best is not None and best.value is not None
    assert len(client.trials(study.id)) == 3

    page = httpx.get(f"{served}/", timeout=10)
    assert page.status_code == 200 and 'src="js/app.js"' in page.text
    # Every static file the server ships is served, byte for byte as in the source.
    for name in sorted(relative(STATIC)):
        if name.startswith(RECIPE) or "node_modules" in name:
            continue
        answer = httpx.get(f"{served}/{name}", timeout=10)
        assert answer.status_code == 200, name
        assert answer.content == (STATIC / name).read_bytes(), name
    assert httpx.get(f"{served}/{RECIPE}package.json", timeout=10).status_code == 404
    docs = httpx.get(f"{served}/docs", timeout=10)
    assert docs.status_code == 200 and "swagger-ui-bundle.js" in docs.text

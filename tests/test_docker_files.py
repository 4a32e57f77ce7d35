"""What can be checked of docker/ without a container engine: the compose file parses and
wires PostgreSQL, one server and scalable workers with health checks; the images build the
wheel in a first stage and install it, with the right extra, after a pinned CPU torch;
every command and AD_* variable they use is one the real CLIs and settings know."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path
from typing import Any

import pytest
import yaml
from sqlalchemy.engine import make_url

from adservice.settings import Settings
from tests.program_checks import check_command, check_environment

REPO = Path(__file__).resolve().parents[1]
DOCKER = REPO / "docker"
IMAGES = {"adserver": "service.Dockerfile", "worker": "worker.Dockerfile"}
EXTRAS = {"service.Dockerfile": "service", "worker.Dockerfile": "worker"}


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    document = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    assert isinstance(document, dict)
    return document


def dockerfile(name: str) -> str:
    return (DOCKER / name).read_text()


def instructions(text: str) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with continuation lines joined and comments dropped."""
    joined = re.sub(r"\\\n", " ", text)
    lines = [line.strip() for line in joined.splitlines()]
    return [
        (line.split(None, 1)[0].upper(), line.split(None, 1)[1] if " " in line else "")
        for line in lines
        if line and not line.startswith("#")
    ]


def stages(text: str) -> list[list[tuple[str, str]]]:
    """The build stages, each from its FROM on."""
    found: list[list[tuple[str, str]]] = []
    for step in instructions(text):
        if step[0] == "FROM":
            found.append([])
        found[-1].append(step)
    return found


def exec_form(arguments: str) -> list[str]:
    value = json.loads(arguments)
    assert isinstance(value, list) and all(isinstance(part, str) for part in value)
    return value


def test_compose_has_postgres_one_server_and_scalable_workers(compose: dict[str, Any]) -> None:
    services = compose["services"]
    assert set(services) == {"postgres", "adserver", "worker"}
    assert services["postgres"]["image"].startswith("postgres:")
    assert "pg_isready" in " ".join(services["postgres"]["healthcheck"]["test"])
    assert "/healthz" in " ".join(services["adserver"]["healthcheck"]["test"])
    assert services["adserver"]["depends_on"]["postgres"]["condition"] == "service_healthy"
    assert services["worker"]["depends_on"]["adserver"]["condition"] == "service_healthy"
    # `--scale worker=N` needs workers without a fixed name or host port.
    assert "container_name" not in services["worker"] and "ports" not in services["worker"]
    for service, image in IMAGES.items():
        build = services[service]["build"]
        assert (DOCKER / build["context"] / build["dockerfile"]).resolve() == DOCKER / image
    assert set(compose["volumes"]) >= {"pgdata", "artifacts"}


def test_server_talks_to_the_postgres_service_with_auth_on(compose: dict[str, Any]) -> None:
    postgres = compose["services"]["postgres"]["environment"]
    server = compose["services"]["adserver"]["environment"]
    url = make_url(re.sub(r"\$\{(\w+):-([^}]*)\}", r"\2", server["AD_DATABASE_URL"]))
    assert url.drivername == "postgresql+psycopg"
    assert (url.host, url.port) == ("postgres", 5432)
    assert url.username == postgres["POSTGRES_USER"]
    assert url.database == postgres["POSTGRES_DB"]
    assert str(url.password) == re.sub(r"\$\{\w+:-([^}]*)\}", r"\1", postgres["POSTGRES_PASSWORD"])
    assert str(server["AD_AUTH"]).lower() == "true"
    assert Settings.model_validate({"auth": server["AD_AUTH"]}).auth is True
    workers = compose["services"]["worker"]["environment"]
    assert workers["AD_SERVER_URL"] == f"http://adserver:{server['AD_PORT']}"
    assert "AD_TOKEN" in workers


@pytest.mark.parametrize("service", ["adserver", "worker"])
def test_compose_commands_and_variables_match_the_clis(
    compose: dict[str, Any], service: str
) -> None:
    spec = compose["services"][service]
    command = spec["command"]
    argv = command if isinstance(command, list) else shlex.split(command)
    check_command(argv)
    check_environment(argv[0], spec["environment"])


@pytest.mark.parametrize("image", list(EXTRAS))
def test_image_builds_the_wheel_then_installs_it_after_cpu_torch(image: str) -> None:
    build, final = stages(dockerfile(image))
    assert build[0] == ("FROM", "python:3.11-slim AS wheel")
    build_runs = [arguments for kind, arguments in build if kind == "RUN"]
    assert build_runs == ["pip wheel --no-deps --wheel-dir /wheels ."]
    assert final[0] == ("FROM", "python:3.11-slim")
    runs = [arguments for kind, arguments in final if kind == "RUN"]
    torch = next(i for i, run in enumerate(runs) if "torch" in run)
    assert "torch==2.13.0" in runs[torch] and "/whl/cpu" in runs[torch]
    package = next(i for i, run in enumerate(runs) if "activedesign-*.whl" in run)
    assert f'.whl)[{EXTRAS[image]}]"' in runs[package]
    assert torch < package
    assert not [run for run in runs if "pip install -e" in run or '".[' in run]
    # The final image gets the wheel and nothing of the source tree.
    copies = [arguments.split() for kind, arguments in final if kind == "COPY"]
    assert copies == [["--from=wheel", "/wheels", "/tmp/wheels"]]
    assert ("USER", "root") not in final and any(kind == "USER" for kind, _ in final)


@pytest.mark.parametrize("image", list(EXTRAS))
def test_image_command_and_environment_match_the_cli(image: str) -> None:
    steps = instructions(dockerfile(image))
    (command,) = [exec_form(arguments) for kind, arguments in steps if kind == "CMD"]
    check_command(command)
    env: dict[str, str] = {}
    for kind, arguments in steps:
        if kind == "ENV":
            env |= dict(pair.split("=", 1) for pair in shlex.split(arguments))
    check_environment(command[0], env)
    for kind, arguments in steps:
        if kind == "HEALTHCHECK":
            assert "/healthz" in arguments


@pytest.mark.parametrize("image", list(EXTRAS))
def test_image_copies_only_what_exists_and_is_not_ignored(image: str) -> None:
    steps = instructions(dockerfile(image))
    ignore = (DOCKER / f"{image}.dockerignore").read_text().splitlines()
    allowed = {line[1:] for line in ignore if line.startswith("!")}
    for kind, arguments in steps:
        if kind == "COPY" and not arguments.startswith("--from="):
            *sources, _target = arguments.split()
            for source in sources:
                assert (REPO / source).exists(), source
                assert source in allowed, f"{source} is excluded by the .dockerignore"


@pytest.mark.parametrize("image", list(EXTRAS))
def test_the_wheel_is_built_from_everything_it_ships(image: str) -> None:
    """The wheel carries the migrations (setup.py copies migrations/ into
    adservice/migrations, tests/test_wheel.py), so its build stage copies them, setup.py and
    MANIFEST.in; in this checkout (an editable install) the server reads migrations/."""
    from adservice.db import MIGRATIONS_DIR

    assert MIGRATIONS_DIR == REPO / "migrations"
    build, _final = stages(dockerfile(image))
    copied = {
        source for kind, arguments in build if kind == "COPY" for source in arguments.split()[:-1]
    }
    assert copied >= {"setup.py", "MANIFEST.in", "pyproject.toml", "migrations", "service"}
    ignore = (DOCKER / f"{image}.dockerignore").read_text().splitlines()
    assert "**/node_modules" in ignore


def test_the_deploy_doc_explains_scaling_out() -> None:
    doc = (REPO / "docs" / "deploy.md").read_text()
    section = doc.split("## One machine to many", 1)[1].split("\n## ", 1)[0]
    for needed in ("--scale worker=", "AD_DATABASE_URL", "token create --role worker"):
        assert needed in section

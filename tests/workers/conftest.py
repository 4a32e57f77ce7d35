from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from adclient.designs import Design
from adclient.plugins import catalogue
from adworker import designs
from tests.servers import ServerProcess
from tests.workers.processes import WorkerProcess
from tests.workers.robots import write_urdf


@pytest.fixture
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    """A real adserver on a fresh SQLite file (test_plugins_e2e has its own)."""
    process = ServerProcess(
        database_url=f"sqlite:///{tmp_path / 'studies.db'}", workdir=tmp_path
    ).start()
    yield process
    process.stop()


@pytest.fixture
def workers(tmp_path: Path) -> Iterator[Callable[..., WorkerProcess]]:
    started: list[WorkerProcess] = []

    def start(server: ServerProcess, worker_id: str, *args: str) -> WorkerProcess:
        worker = WorkerProcess(server, tmp_path, worker_id, *args)
        started.append(worker)
        return worker

    yield start
    for worker in started:
        worker.stop()


@pytest.fixture
def env_of(tmp_path: Path):
    """An installed task's env for a design (a Design, or the name of a reference design in
    adworker.designs), built as the worker builds it: the task's factory, given the
    design, its URDF and the task's options model."""
    numbers = itertools.count()

    def make(task: str, design: Design | str, render_mode: str | None = None, **options: object):
        robot = getattr(designs, design)() if isinstance(design, str) else design
        urdf_path = write_urdf(robot, tmp_path / f"robot-{next(numbers)}.urdf")
        spec = catalogue().task(task)
        return spec.load_factory()(
            design=robot,
            urdf_path=urdf_path,
            options=spec.options.model_validate(options),
            render_mode=render_mode,
        )

    return make

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from adclient.designs import Design
from adclient.plugins import catalogue
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import WorkerProcess, pip_install_target, plugin_path
from adworker import designs
from tests.workers.robots import write_urdf

PLUGIN_FIXTURE = Path(__file__).resolve().parent / "plugin_fixture"


@pytest.fixture(scope="session")
def plugin_site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """tests/workers/plugin_fixture as ``pip install`` leaves it: a package and its
    dist-info with the entry points, in a folder of its own that only processes given it
    on their PYTHONPATH see (built from a copy: the build writes files)."""
    site = pip_install_target(PLUGIN_FIXTURE, tmp_path_factory.mktemp("plugin"))
    assert (site / "adplugin_reach").is_dir()
    return site


@pytest.fixture
def server(tmp_path: Path, new_sqlite_url: Callable[[], str]) -> Iterator[ServerProcess]:
    """A real adserver on a fresh SQLite file (``plugin_server``: one that has the plugin)."""
    process = ServerProcess(database_url=new_sqlite_url(), workdir=tmp_path).start()
    yield process
    process.stop()


@pytest.fixture
def plugin_server(
    plugin_site: Path, tmp_path: Path, new_sqlite_url: Callable[[], str]
) -> Iterator[ServerProcess]:
    """A real adserver that has the test plugin (its tasks, and the hold learner)."""
    process = ServerProcess(
        database_url=new_sqlite_url(),
        workdir=tmp_path,
        env=plugin_path(plugin_site),
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
    design, its URDF and the task's options model (``simulator``: on that engine)."""
    numbers = itertools.count()

    def make(
        task: str,
        design: Design | str,
        render_mode: str | None = None,
        simulator: str = "pybullet",
        **options: object,
    ):
        robot = getattr(designs, design)() if isinstance(design, str) else design
        urdf_path = write_urdf(robot, tmp_path / f"robot-{next(numbers)}.urdf")
        spec = catalogue().task(task)
        return spec.load_factory()(
            design=robot,
            urdf_path=urdf_path,
            options=spec.options.model_validate(options),
            render_mode=render_mode,
            simulator=simulator,
        )

    return make

"""The SDK stays light: its client and CLI never pull in the server's or worker's stack;
reading the task catalogue (what the server does to check a study file) imports no
simulator, and a function worker imports neither PyBullet nor torch."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
HEAVY = (
    "fastapi",
    "starlette",
    "sqlalchemy",
    "torch",
    "botorch",
    "pybullet",
    "gymnasium",
    "stable_baselines3",
    "optuna",  # adclient.optuna imports it: only those who use that module have it
    "adservice",
    "adworker",
)


def _heavy_modules_after(code: str, allowed: tuple[str, ...] = ()) -> list[str]:
    """The heavy top-level packages imported by a fresh interpreter running ``code``."""
    heavy = tuple(name for name in HEAVY if name not in allowed)
    probe = (
        f"{code}\n"
        "import sys\n"
        f"print(','.join(sorted({{m.split('.')[0] for m in sys.modules}} & {set(heavy)!r})))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True
    )
    return [name for name in result.stdout.strip().split(",") if name]


def test_client_and_cli_import_without_heavy_packages() -> None:
    assert _heavy_modules_after("import adclient, adclient.client, adclient.cli") == []


def test_checking_a_study_against_the_catalogue_imports_no_simulator() -> None:
    code = (
        "import yaml\n"
        "from adclient.plugins import catalogue\n"
        "from adclient.schemas import StudyCreate\n"
        "assert {'stand-up', 'diagonal-gesture', 'lift-highest'} <= set(catalogue().tasks)\n"
        f"StudyCreate.model_validate(yaml.safe_load(open({str(EXAMPLES / 'stand-up.yaml')!r})))\n"
    )
    assert _heavy_modules_after(code) == []


def test_a_function_worker_imports_no_simulator_or_torch(tmp_path) -> None:
    (tmp_path / "scorer.py").write_text("def score(job):\n    return job.params['x'] * 2\n")
    code = (
        "import adworker.cli\n"
        "from datetime import UTC, datetime\n"
        "from pathlib import Path\n"
        "from adclient.schemas import Job\n"
        "from adworker.worker import WorkerConfig, make_runner\n"
        f"config = WorkerConfig(server='http://127.0.0.1:1', function='scorer:score',"
        f" task='double', app_dir=Path({str(tmp_path)!r}))\n"
        "runner = make_runner(config)\n"
        "job = Job(trial_id=1, study_id=1, number=0, attempt=1, vector=[0.5],"
        " params={'x': 1.5}, task={'name': 'double', 'external': True},"
        " space={'type': 'box', 'params': [{'name': 'x', 'low': 0, 'high': 3}]},"
        " representation=None, lease_expires_at=datetime.now(UTC))\n"
        f"outcome = runner(job, Path({str(tmp_path / 'job')!r}), lambda: None)\n"
        "assert runner.tasks() == ['double'] and outcome.value == 3.0, outcome\n"
    )
    assert _heavy_modules_after(code, allowed=("adworker",)) == []


def test_the_sdk_never_imports_its_process_harness() -> None:
    code = "import adclient, adclient.client, adclient.cli, sys\nimport adclient.plugins\n"
    code += "print(sorted(m for m in sys.modules if m.startswith('adclient.testing')))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"


def test_the_process_harness_starts_the_programs_and_imports_neither() -> None:
    """``adclient.testing`` runs adserver and adworker by command: every module of it
    imports neither (the database and scrape readers may import SQLAlchemy)."""
    harness = EXAMPLES.parent / "client" / "adclient" / "testing"
    names = sorted(path.stem for path in harness.glob("*.py") if path.stem != "__init__")
    assert {"servers", "workers", "postgres", "load", "attacks"} <= set(names)
    code = "".join(f"import adclient.testing.{name}\n" for name in names)
    assert _heavy_modules_after(code, allowed=("sqlalchemy",)) == []

"""What the shared controller's modular policy costs per design against the plain MLP
(issue 38): CPU seconds of ``PPOLearner.train`` on one design of a task, the MLP from
scratch and the modular policy from the study's initial weights, the same steps, one
torch thread, in this process, after a first short training of each (imports and
torch's first calls out of the figure).

Reported (``BENCH`` lines, for bench/compare.py): each arm's CPU seconds, the median of
``--runs`` alternating runs, and their ratio modular / MLP.

Run: ``.venv/bin/python bench/modular_cost.py [--task stand-up] [--steps 8192]
[--runs 3]``; against a baseline commit:
``.venv/bin/python bench/compare.py --baseline REV --runs 3 -- bench/modular_cost.py``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from adclient.testing.figures import emit  # noqa: E402


def train_cpu(task: str, arm: str, steps: int, folder: Path) -> float:
    """CPU seconds of one training of design 0 of bench/shared_policy.py's ``task``."""
    from adworker.learners import PPOLearner
    from adworker.starts import SCRATCH, Shared
    from bench.shared_policy import make_env

    env = make_env(task, 0, folder)
    start: Any = SCRATCH if arm == "mlp" else Shared(None, steps=steps, seed=0)
    began = time.process_time()
    PPOLearner().train(env, steps=steps, seed=0, start=start)
    cpu = time.process_time() - began
    env.close()
    return cpu


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="stand-up")
    parser.add_argument("--steps", type=int, default=8192)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    cpu: dict[str, list[float]] = {"mlp": [], "modular": []}
    with tempfile.TemporaryDirectory(prefix="bench-modular-") as workdir:
        folder = Path(workdir)
        for arm in cpu:
            train_cpu(args.task, arm, 1024, folder)
        for _ in range(args.runs):
            for arm in cpu:
                cpu[arm].append(train_cpu(args.task, arm, args.steps, folder))
    mlp, modular = statistics.median(cpu["mlp"]), statistics.median(cpu["modular"])
    print(f"{args.task}, {args.steps} steps: MLP {cpu['mlp']} s, modular {cpu['modular']} s")
    emit("mlp CPU", mlp, higher_is_better=False, unit="s")
    emit("modular CPU", modular, higher_is_better=False, unit="s")
    emit("modular / mlp", modular / mlp, higher_is_better=False, unit="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

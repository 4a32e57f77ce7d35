"""The GPU path (issue 59): env steps per second of a MuJoCo Warp batch of designs of one
tree (adworker.gpu.warp_batch), random actions (the batch's limit) and PPO with one
policy per design (adworker.gpu.ppo), and designs per GPU-minute at a 1M-step budget.

    python bench/gpu.py [--designs 4] [--worlds 16] [--steps 64] [--ppo-steps 2048] \\
        [--device cuda:0|cpu] [--json FILE]

On a GPU (the issue's figures), one command:

    .venv/bin/python bench/gpu.py --designs 8 --worlds 1024 --steps 200 --ppo-steps 1000000

Designs: stand-up's arch of three links (adworker.designs.arch_chain), its link lengths
spread from 0.3 to 0.5 m and masses from 1 to 2 kg across ``--designs`` (one tree, so
one batch), ``--worlds`` worlds each, on MuJoCo's world as the CPU engine builds it.

Figures: ``build_s`` (put_model and make_data) and ``first_step_s`` (the kernels loaded,
or compiled on a fresh Warp cache: ``WARP_CACHE_PATH`` to choose where) in wall seconds;
``random`` env (control) steps per second of the whole batch, wall and, on the CPU
device, per CPU-second of this process; ``ppo`` the same of PPO's ``train`` on
``--ppo-steps`` env steps per design (the rollout, the update and the evaluation
episode); ``designs_per_gpu_minute_1m``: designs trained to 1M env steps a minute at
``ppo``'s rate (all the batch's designs together). Goal (a GPU only): ``random`` and
``ppo`` at least 200,000 env steps per second for a batch of designs on one card.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from adclient.plugins import catalogue
from adclient.testing.figures import emit
from adclient.urdf import design_to_urdf

GOAL_STEPS_PER_S = 200_000
BUDGET = 1_000_000


def _envs(count: int, folder: Path) -> list[Any]:
    from adworker import designs

    spec = catalogue().task("stand-up")
    envs = []
    for k in range(count):
        share = k / max(1, count - 1)
        design = designs.arch_chain(length=0.3 + 0.2 * share, mass=1.0 + share)
        path = folder / f"design-{k}.urdf"
        path.write_text(design_to_urdf(design))
        envs.append(
            spec.load_factory()(
                design=design,
                urdf_path=path,
                options=spec.options.model_validate({}),
                simulator="mujoco",
            )
        )
    return envs


def _timed(run: Any) -> tuple[Any, float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    value = run()
    return value, time.perf_counter() - wall, time.process_time() - cpu


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--designs", type=int, default=4)
    parser.add_argument("--worlds", type=int, default=16, help="worlds per design")
    parser.add_argument("--steps", type=int, default=64, help="control steps to time")
    parser.add_argument("--ppo-steps", type=int, default=2048, help="env steps per design")
    parser.add_argument("--device", default=None)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    import torch
    import warp as wp

    from adworker.gpu.ppo import GpuPPOOptions, train
    from adworker.gpu.warp_batch import WarpBatch, default_device, mujoco_version

    torch.set_num_threads(1)
    device = args.device or default_device()
    on_gpu = wp.get_device(device).is_cuda
    figures: dict[str, Any] = {
        "device": wp.get_device(device).name if on_gpu else "cpu (Warp's CPU device)",
        "versions": mujoco_version(),
        "designs": args.designs,
        "worlds_per_design": args.worlds,
    }
    with tempfile.TemporaryDirectory() as folder:
        envs = _envs(args.designs, Path(folder))
        batch, figures["build_s"], _ = _timed(lambda: WarpBatch(envs, args.worlds, device=device))
        figures["per_world_fields"] = batch.per_world_fields
        g = torch.Generator(device=batch.design_of_world().device).manual_seed(0)

        def random_actions() -> Any:
            shape = (batch.nworld, batch.joints)
            return torch.rand(shape, generator=g, device=g.device) * 2 - 1

        batch.reset(seed=0)
        _, figures["first_step_s"], _ = _timed(lambda: batch.step(random_actions()))

        def random_steps() -> None:
            for _ in range(args.steps):
                batch.step(random_actions())
            wp.synchronize_device(device)

        _, wall, cpu = _timed(random_steps)
        steps = args.steps * batch.nworld
        figures["random_steps_per_s"] = steps / wall
        figures["random_steps_per_cpu_s"] = steps / cpu
        figures["physics_steps_per_s"] = steps * batch.frame_skip / wall
        if args.ppo_steps:
            options = GpuPPOOptions(steps=args.ppo_steps)
            (_, result), wall, cpu = _timed(lambda: train(batch, options))
            trained = result.env_steps * batch.designs
            figures["ppo_steps_per_s"] = trained / wall
            figures["ppo_steps_per_cpu_s"] = trained / cpu
            figures["ppo_scores"] = result.scores
            figures["designs_per_gpu_minute_1m"] = figures["ppo_steps_per_s"] * 60 / BUDGET
        for env in envs:
            env.close()
    print(json.dumps(figures, indent=2))
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=2))
    rate = "per_s" if on_gpu else "per_cpu_s"
    emit("gpu.random_steps", figures[f"random_steps_{rate}"], higher_is_better=True, unit=rate)
    if args.ppo_steps:
        emit("gpu.ppo_steps", figures[f"ppo_steps_{rate}"], higher_is_better=True, unit=rate)
    if on_gpu:
        best = figures.get("ppo_steps_per_s", figures["random_steps_per_s"])
        verdict = "met" if best >= GOAL_STEPS_PER_S else "missed"
        print(f"goal: >= {GOAL_STEPS_PER_S:,} env steps/s on one card: {best:,.0f} ({verdict})")
    else:
        print("goal: >= 200,000 env steps/s is a GPU's: not measured on the CPU device")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    sys.exit(main())

"""The GPU path (issue 59): designs of one tree stepped together on MuJoCo Warp
(:mod:`adworker.gpu.warp_batch`), a PPO with one policy per design trained on that batch
(:mod:`adworker.gpu.ppo`), and the worker mode that leases several trials of one tree
and trains them in one batch (:mod:`adworker.gpu.jobs`).

Everything here imports ``warp`` and ``mujoco_warp`` (the ``gpu`` extra of
pyproject.toml): nothing else in the worker imports this package, so a worker without
the extra runs as before. On a machine without a GPU it runs on Warp's CPU device (the
tests do), far slower than MuJoCo's C engine: the CPU device is for checking, the
speed is the GPU's (bench/gpu.py).
"""

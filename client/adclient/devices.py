"""Where torch runs: the check ``adserver`` and ``adworker`` make before starting on cuda,
so a missing GPU stops them at start with the reason, not at the first ask or job."""

from __future__ import annotations

LEARNER_DEVICE_VARIABLE = "AD_LEARNER_DEVICE"
"""The torch device a learner trains on, in every job process: ``adworker
--learner-device`` sets it (a learner plugin with a network reads it too)."""


def device_problem(device: str) -> str | None:
    """Why torch cannot use ``device`` here, or None when it can (cpu always can)."""
    if device == "cpu":
        return None
    import torch  # only when a GPU is asked for: the SDK itself needs no torch

    if torch.version.cuda is None:
        return f"this torch ({torch.__version__}) is built without CUDA; install a CUDA build"
    if not torch.cuda.is_available():
        return "torch finds no CUDA GPU on this machine (check the driver and CUDA_VISIBLE_DEVICES)"
    return None

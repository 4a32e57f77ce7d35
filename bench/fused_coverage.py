"""Where the search box of a multi-structure study sends its vectors: structures, clipped specs.

    .venv/bin/python bench/fused_coverage.py [--samples 4000]

For the lift-highest example (six trees), draws uniform vectors in the search box
of each encoding (``mixed``, the default; ``fused``, the preprint's; ``onehot``),
decodes each, and reports per structure: the share of the box that decodes to it,
the mean share of its used specs that land on a bound (the decoder clips them to
[0, 1]), and the share of vectors whose every used spec is clipped (a corner
design). A proposer exploring the box sees these designs, so this explains
bench/paper.py's comparison of the encodings. Uses the working tree's code.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.paperlib import study_body


def coverage(samples: int, encoding: str) -> list[tuple[str, float, float, float]]:
    from adclient.decode import spec_layout, spec_vector
    from adclient.design import DesignSpace
    from adservice.representation import build_representation

    body = study_body("lift-highest")["space"]
    space = DesignSpace.model_validate({**body, "encoding": encoding})
    representation = build_representation(space)
    layout = spec_layout(space)
    low, high = np.asarray(representation.bounds)
    rng = np.random.default_rng(0)
    count = np.zeros(len(layout.structures))
    clipped = np.zeros(len(layout.structures))
    corner = np.zeros(len(layout.structures))
    for _ in range(samples):
        vector = low + rng.random(low.size) * (high - low)
        structure, x = spec_vector(representation, vector)
        used = x[layout.used_slots(layout.structures[structure])]
        at_bound = (used <= 1e-9) | (used >= 1 - 1e-9)
        count[structure] += 1
        clipped[structure] += at_bound.mean()
        corner[structure] += at_bound.all()
    rows = []
    for index, edges in enumerate(layout.structures):
        n = max(count[index], 1)
        name = ",".join(f"{p}-{c}" for p, c in edges)
        rows.append((name, count[index] / samples, clipped[index] / n, corner[index] / n))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=4000)
    args = parser.parse_args()
    print(f"{args.samples} uniform vectors per encoding")
    for encoding in ("mixed", "fused", "onehot"):
        rows = coverage(args.samples, encoding)
        print(f"\n{encoding}:")
        print("| structure | share of box | specs on a bound | all specs on a bound |")
        print("| --- | ---: | ---: | ---: |")
        for name, share, clipped, corner in rows:
            print(f"| {name} | {share:.2f} | {clipped:.2f} | {corner:.2f} |")
        total_clipped = sum(share * c for _, share, c, _ in rows)
        print(f"| all | 1.00 | {total_clipped:.2f} | {sum(s * k for _, s, _, k in rows):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

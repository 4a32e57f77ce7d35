"""Catalogue choices (issue 28): a design space whose joints choose their motor from a
catalogue of eight servos (the model relates servos by their entries) against the same
problem with each motor a plain categorical param, through a real ``adserver``.

The score is synthetic and cheap (no physics), so the proposers are what is compared:
a three-joint arm held out horizontally with a 0.3 kg payload at its tip. Each joint
must hold the links beyond it (0.6 kg/m), the servos mounted further out and the
payload; its servo's effort short of that torque costs ``DEFICIT`` per unit of relative
shortfall. The score is the arm's reach (m) less the deficits and ``COST`` per unit of
the servos' price: the best arms are long, with a strong servo at the shoulder and
light ones further out, so it rewards torque-to-mass and penalises waste.

Arms: ``catalogue`` (examples/catalogue-arm.yaml's servos, ``joint: {choose: servos}``,
link lengths searched) and ``categorical`` (a box: three lengths and three categorical
params naming the servo), each with ``qei`` and, as a floor, ``random``. Each study:
``--trials`` evaluations, proposer seeded by the run's seed.

Goal (issue 28): qei's median best by 30 evaluations on the catalogue at or above the
categorical one's (10 seeds); the lower quartile is reported beside it.

Run: ``.venv/bin/python bench/catalogue.py`` (about 15 minutes on two cores);
``--seeds 2 --trials 10`` to check it runs. Results append to
bench/results/catalogue.jsonl; ``--report`` prints the table.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from adclient import Client  # noqa: E402
from adclient.testing.servers import ServerProcess  # noqa: E402
from bench.paperlib import append_jsonl, quantiles, read_jsonl  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "catalogue.jsonl"
EXAMPLE = ROOT / "examples" / "catalogue-arm.yaml"
ARMS = ("catalogue", "categorical")
JOINTS = ("b", "c", "d")
G = 9.81
LINK_KG_PER_M = 0.6
PAYLOAD_KG = 0.3
DEFICIT = 0.5
COST = 2e-4


def servos() -> dict[str, dict[str, float]]:
    body = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    return body["space"]["catalogues"]["servos"]


def score(lengths: list[float], motors: list[str], catalogue: dict[str, dict[str, float]]) -> float:
    """Reach less the torque shortfalls and the servos' price (see the module docstring)."""
    shortfall = 0.0
    for j in range(len(lengths)):
        torque, reach = 0.0, 0.0
        for k in range(j, len(lengths)):
            torque += LINK_KG_PER_M * lengths[k] * G * (reach + lengths[k] / 2)
            reach += lengths[k]
            if k + 1 < len(lengths):  # the next joint's servo sits at this link's end
                torque += catalogue[motors[k + 1]]["mass"] * G * reach
        torque += PAYLOAD_KG * G * reach
        effort = catalogue[motors[j]]["effort"]
        shortfall += max(0.0, torque - effort) / effort
    price = sum(catalogue[m]["cost"] for m in motors)
    return sum(lengths) - DEFICIT * shortfall - COST * price


def study_body(arm: str, proposer: str, seed: int, trials: int) -> dict[str, Any]:
    body = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    body.pop("task")
    body.update(
        name=f"catalogue-{arm}-{proposer}-{seed}",
        max_trials=trials,
        proposer={"name": proposer, "seed": seed},
    )
    if arm == "categorical":
        names = list(body["space"]["catalogues"]["servos"])
        length = body["space"]["parts"]["link"]["length"]
        params = [
            {"name": f"{j}_length", "low": length["low"], "high": length["high"]} for j in JOINTS
        ]
        params += [{"name": f"{j}_motor", "type": "categorical", "choices": names} for j in JOINTS]
        body["space"] = {"type": "box", "params": params}
    return body


def lengths_and_motors(arm: str, params: dict[str, Any]) -> tuple[list[float], list[str]]:
    if arm == "categorical":
        return [params[f"{j}_length"] for j in JOINTS], [params[f"{j}_motor"] for j in JOINTS]
    return [params[f"{j}.length"] for j in JOINTS], [params[f"{j}.joint.choice"] for j in JOINTS]


def run_one(client: Client, arm: str, proposer: str, seed: int, trials: int) -> dict[str, Any]:
    catalogue = servos()
    study = client.create_study(study_body(arm, proposer, seed, trials))
    values = []
    for _ in range(trials):
        trial = study.ask()
        value = score(*lengths_and_motors(arm, trial.params), catalogue)
        study.tell(trial, value)
        values.append(value)
    best = [max(values[: i + 1]) for i in range(len(values))]
    return {"arm": arm, "proposer": proposer, "seed": seed, "trials": trials, "best": best}


def report(runs: list[dict[str, Any]], trials: int) -> str:
    lines = [
        f"| proposer | arm | seeds | best by {trials}: lower quartile | median | upper quartile |",
        "|---|---|---|---|---|---|",
    ]
    for proposer in sorted({r["proposer"] for r in runs}):
        for arm in ARMS:
            chosen = [r["best"][-1] for r in runs if (r["proposer"], r["arm"]) == (proposer, arm)]
            if chosen:
                q1, median, q3 = quantiles(chosen)
                lines.append(
                    f"| {proposer} | {arm} | {len(chosen)} | {q1:.3f} | {median:.3f} | {q3:.3f} |"
                )
    return "\n".join(lines)


def optimum(catalogue: dict[str, dict[str, float]]) -> float:
    """The best score on a grid of lengths (0.1 to 0.4 by 0.025), every servo triple."""
    import itertools

    grid = [0.1 + 0.025 * i for i in range(13)]
    names = list(catalogue)
    best = -float("inf")
    for motors in itertools.product(names, repeat=3):
        for lengths in itertools.product(grid, repeat=3):
            best = max(best, score(list(lengths), list(motors), catalogue))
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--proposers", nargs="+", default=["qei", "random"])
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--report", action="store_true", help="print the table and stop")
    args = parser.parse_args()
    runs = [r for r in read_jsonl(args.results) if r["trials"] == args.trials]
    if not args.report:
        done = {(r["arm"], r["proposer"], r["seed"]) for r in runs}
        with tempfile.TemporaryDirectory(prefix="bench-catalogue-") as folder:
            work = Path(folder)
            server = ServerProcess(database_url=f"sqlite:///{work / 'studies.db'}", workdir=work)
            server.start()
            try:
                with Client(server.url) as client:
                    for seed in range(args.seeds):
                        for proposer in args.proposers:
                            for arm in ARMS:
                                if (arm, proposer, seed) in done:
                                    continue
                                run = run_one(client, arm, proposer, seed, args.trials)
                                append_jsonl(args.results, run)
                                runs.append(run)
                                print(
                                    f"{proposer} {arm} seed {seed}: {run['best'][-1]:.3f}",
                                    flush=True,
                                )
            finally:
                server.stop()
    print(report(runs, args.trials))
    print(f"\noptimum on a 0.025 m grid: {optimum(servos()):.3f}")


if __name__ == "__main__":
    main()

"""What the worst of issue 58 from one plain ``user`` token costs another user's study on
the same server (adclient.testing.neighbours): the ordinary user's reads and leases in
noisy blocks against quiet blocks of the same run, as ratios of their medians and of
their 90th percentiles.

A real ``adserver`` on a fresh SQLite file with auth on (``AD_OWNER_STORAGE_BYTES`` 20 MB
so the uploads reach the quota within a block; every other budget at its default), the
noisy user's attacks in a process of their own at nice 19 (its client is another
machine's cost). Prints each figure as a ``BENCH`` line and a table of what the attacks
were answered.

    python bench/noisy_neighbour.py [--blocks 4] [--per-block 30]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from adclient.testing.figures import emit
from adclient.testing.neighbours import Probes, client, measure, ordinary_studies
from adclient.testing.servers import ServerProcess, make_token


def percentile(samples: list[float], share: float) -> float:
    ordered = sorted(samples)
    return ordered[min(len(ordered) - 1, int(share * len(ordered)))]


def report(probes: Probes) -> None:
    for what in ("reads", "leases"):
        samples = getattr(probes, what)
        quiet, noisy = samples["quiet"], samples["noisy"]
        figures = {
            f"{what}_quiet_median_ms": (1e3 * statistics.median(quiet), "ms"),
            f"{what}_noisy_median_ms": (1e3 * statistics.median(noisy), "ms"),
            f"{what}_median_ratio": (probes.ratio(what), "x"),
            f"{what}_p90_ratio": (percentile(noisy, 0.9) / percentile(quiet, 0.9), "x"),
        }
        for metric, (value, unit) in figures.items():
            emit(metric, value, higher_is_better=False, unit=unit)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blocks", type=int, default=4)
    parser.add_argument("--per-block", type=int, default=30)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="noisy-") as folder:
        work = Path(folder)
        server = ServerProcess(
            database_url=f"sqlite:///{work / 'studies.db'}",
            workdir=work,
            env={"AD_AUTH": "1", "AD_OWNER_STORAGE_BYTES": "20000000"},
        ).start()
        try:
            alice = make_token(server, "user", name="alice")
            with (
                client(server.url, make_token(server, "user", name="bob")) as bob,
                client(server.url, make_token(server, "worker", name="shared")) as worker,
            ):
                studies = ordinary_studies(bob, trials=100_000)
                probes, record = measure(
                    bob,
                    worker,
                    studies,
                    server.url,
                    alice,
                    blocks=args.blocks,
                    per_block=args.per_block,
                )
        finally:
            server.stop()
    report(probes)
    print("| the noisy user's request | answered | count |\n| --- | --- | --- |")
    for key, count in sorted(record.answers.items()):
        what, _, status = key.rpartition(" ")
        print(f"| {what} | {status} | {count} |")
    print(f"breaches: {record.breaches or 'none'}; probe failures: {probes.failures or 'none'}")


if __name__ == "__main__":
    main()

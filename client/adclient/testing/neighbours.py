"""Noisy neighbours on one real server (issue 58): one user sends the worst of what a
plain ``user`` token may send, while another user's ordinary study is read, leased and
told beside it. The test (tests/service/test_noisy_neighbour_e2e.py) and the bench
(bench/noisy_neighbour.py) both run :func:`measure`.

What the noisy user, alice, does while noise is on, each in threads of its own and in a
loop until it is told to stop:

- ``creations``: design spaces of random 32-link trees (the issue's 198 s creation and
  smaller ones just inside the similarity's budget), each abandoned by its client after a
  second, several at once;
- ``harmful``: a template with an entity bomb, a study whose learner options would hold
  a worker for hours (``gradient_steps: 1e9``): each must be refused;
- ``leases``: leases with her own token for the ordinary user's tasks, which must never
  hand her one of his trials;
- ``uploads``: artifacts of 1 MB to a trial of her own, past her storage quota;
- ``expansions``: asks of a template study whose every URDF is large, past its byte
  limits.

The ordinary user, bob, has a study told by a real worker (trials completing) and a study
his probe leases with the shared worker token and tells: each probe is a read of his
study (``GET /api/v1/studies/{id}``) and a lease and tell of his probed study, timed.
Quiet and noisy blocks alternate, so that the machine's own load falls on both alike.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import statistics
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import httpx

PROBE_TASK = "neighbour-probe"
"""The external task of bob's probed study: only the probe leases it."""
ORDINARY_TASK = "neighbour-ordinary"
"""The external task of bob's worked study: a real worker serves it."""
XACRO = 'xmlns:xacro="http://www.ros.org/wiki/xacro"'
ARM = (
    '<link name="base"><visual><geometry><box size="${size} 0.1 0.1"/></geometry></visual>'
    '</link><link name="arm"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual>'
    '</link><joint name="j" type="revolute"><parent link="base"/><child link="arm"/>'
    '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
)


def client(url: str, token: str, timeout: float = 60.0) -> httpx.Client:
    """One user's HTTP client (a pool of connections for its threads)."""
    return httpx.Client(
        base_url=url,
        headers={"Authorization": f"Bearer {token}", "X-Activedesign-Client": "neighbours"},
        timeout=timeout,
        verify=False,
        limits=httpx.Limits(max_connections=None),
    )


def random_trees_space(count: int, links: int, seed: int) -> dict[str, Any]:
    """A design space of ``count`` distinct random trees over ``links`` instances, each
    rooted at the first (a random parent among the earlier links for every other)."""
    rng = random.Random(seed)
    names = [f"l{index}" for index in range(links)]
    trees: list[list[list[str]]] = []
    seen: set[tuple[int, ...]] = set()
    while len(trees) < count:
        parents = tuple(rng.randrange(index) for index in range(1, links))
        if parents in seen:
            continue
        seen.add(parents)
        trees.append([[names[p], names[c]] for c, p in enumerate(parents, start=1)])
    return {
        "type": "design",
        "parts": {"link": {"shape": "box", "length": {"low": 0.1, "high": 0.3}, "radius": 0.03}},
        "joint": {"type": "revolute", "axis_theta": 0.0, "axis_phi": 0.0},
        "instances": [{"name": name, "part": "link"} for name in names],
        "structures": trees,
        "max_structures": 1000,
        # a creation's cost is the point, not the robots: siblings at rest lie along one
        # line, through each other, and the overlap check would refuse the space at once
        "allow_overlaps": True,
    }


def entity_bomb_template() -> str:
    """The issue's expat amplification: entities referenced far past the document."""
    entities = '<!ENTITY a "' + "x" * 1000 + '"><!ENTITY b "' + "&a;" * 80 + '">'
    return (
        f'<?xml version="1.0"?>\n<!DOCTYPE robot [{entities}]>\n'
        f'<robot name="bomb" {XACRO}>{ARM}<gazebo>{"&b;" * 100}</gazebo></robot>'
    )


def large_template(calls: int = 24) -> str:
    """A macro of a thousand ``<gazebo>`` elements expanded ``calls`` times: each URDF is
    about 1.5 MB (within the server's default limit of one) from a template of 66 kB."""
    unit = '<gazebo reference="base"><sensor name="s" type="ray"/></gazebo>'
    return (
        f'<robot name="big" {XACRO}><xacro:macro name="m">{unit * 1000}</xacro:macro>'
        f"{ARM}{'<xacro:m/>' * calls}</robot>"
    )


SIZE = [{"name": "size", "low": 0.1, "high": 0.2}]


@dataclass
class Record:
    """What the noisy user's requests were answered, by attack and status, and any
    answer that breached another user's study."""

    answers: Counter[str] = field(default_factory=Counter)
    breaches: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def saw(self, attack: str, outcome: str) -> None:
        with self.lock:
            self.answers[f"{attack} {outcome}"] += 1


Attack = Callable[[threading.Event, Record], None]


def _status(call: Callable[..., httpx.Response], *args: Any, **kwargs: Any) -> str:
    """The status ``call(*args, **kwargs)`` was answered, or why it had none."""
    try:
        return str(call(*args, **kwargs).status_code)
    except httpx.TimeoutException:
        return "abandoned"
    except httpx.TransportError as error:
        return type(error).__name__


def creations(url: str, token: str, space: dict[str, Any]) -> Attack:
    """Create a study of ``space`` and abandon it after a second, again and again."""

    def attack(stop: threading.Event, record: Record) -> None:
        body = {"name": "freeze", "space": space, "proposer": {"name": "random"}}
        with client(url, token, timeout=1.0) as http:
            while not stop.is_set():
                record.saw("creation", _status(http.post, "/api/v1/studies", json=body))

    return attack


def harmful(url: str, token: str) -> Attack:
    """A template study with an entity bomb, and a study whose learner would hold a
    worker for hours: both must be refused (4xx)."""
    bodies = [
        {
            "name": "bomb",
            "space": {"type": "template", "template": entity_bomb_template(), "params": SIZE},
            "proposer": {"name": "random"},
            "task": {"name": "stand-up", "learner": "ppo", "train_steps": 1000},
        },
        {
            "name": "greedy",
            "space": random_trees_space(1, 3, seed=0),
            "proposer": {"name": "random"},
            "task": {
                "name": "stand-up",
                "learner": "sac",
                "train_steps": 200,
                "options": {"learner_kwargs": {"gradient_steps": 1_000_000_000}},
            },
        },
    ]

    def attack(stop: threading.Event, record: Record) -> None:
        with client(url, token) as http:
            while not stop.is_set():
                for body in bodies:
                    status = _status(http.post, "/api/v1/studies", json=body)
                    record.saw(f"harmful {body['name']}", status)
                    if status.startswith("2"):
                        record.breaches.append(f"study {body['name']!r} was accepted")
                stop.wait(0.05)

    return attack


def leases(url: str, token: str) -> Attack:
    """Lease the ordinary user's tasks with the noisy user's own token: never a job."""

    def attack(stop: threading.Event, record: Record) -> None:
        body = {"worker_id": "alice-lease", "tasks": [PROBE_TASK, ORDINARY_TASK]}
        with client(url, token) as http:
            while not stop.is_set():
                answer = http.post("/api/v1/jobs/lease", json=body)
                record.saw("lease", str(answer.status_code))
                if answer.status_code == 200:
                    record.breaches.append(f"alice leased {answer.json()['trial_id']}")
                stop.wait(0.05)

    return attack


def uploads(url: str, token: str) -> Attack:
    """Upload 1 MB artifacts to a trial of the noisy user's own, past every limit."""
    chunk = bytes(1_000_000)

    def attack(stop: threading.Event, record: Record) -> None:
        with client(url, token) as http:
            study = http.post(
                "/api/v1/studies",
                json={
                    "name": "hoard",
                    "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
                    "proposer": {"name": "random"},
                },
            ).json()["id"]
            while not stop.is_set():
                asked = http.post(f"/api/v1/studies/{study}/ask", json={"count": 1})
                if asked.status_code != 200:  # past the quota: no new trials either
                    record.saw("upload ask", str(asked.status_code))
                    stop.wait(0.2)
                    continue
                trial_id = asked.json()["trials"][0]["id"]
                for index in range(80):
                    if stop.is_set():
                        return
                    status = _status(
                        http.put,
                        f"/api/v1/trials/{trial_id}/artifacts/blob{index}.bin",
                        content=chunk,
                        headers={"Content-Type": "application/octet-stream"},
                    )
                    record.saw("upload", status)
                    if status == "413":
                        stop.wait(0.05)

    return attack


def expansions(url: str, token: str) -> Attack:
    """Asks of 40 trials of a template study whose URDFs are megabytes each."""

    def attack(stop: threading.Event, record: Record) -> None:
        body = {
            "name": "swell",
            "space": {"type": "template", "template": large_template(), "params": SIZE},
            "proposer": {"name": "random"},
        }
        with client(url, token, timeout=120) as http:
            created = http.post("/api/v1/studies", json=body)
            record.saw("template study", str(created.status_code))
            if created.status_code != 201:
                return
            study = created.json()["id"]
            while not stop.is_set():
                status = _status(http.post, f"/api/v1/studies/{study}/ask", json={"count": 40})
                record.saw("template ask", status)
                stop.wait(0.1)

    return attack


def worst_of_issue_58(url: str, token: str) -> list[Attack]:
    """Every attack above, creations four at a time (two of the issue's 198 s creation,
    two of a space just inside the similarity's budget)."""
    return [
        creations(url, token, random_trees_space(200, 32, seed=1)),
        creations(url, token, random_trees_space(200, 32, seed=2)),
        creations(url, token, random_trees_space(40, 24, seed=3)),
        creations(url, token, random_trees_space(40, 24, seed=4)),
        harmful(url, token),
        leases(url, token),
        uploads(url, token),
        expansions(url, token),
    ]


@contextlib.contextmanager
def noise(url: str, token: str, record: Record) -> Iterator[None]:
    """The noisy user's attacks (:func:`worst_of_issue_58`) running while the block runs,
    in a process of their own (in the prober's process their threads would take its
    GIL, and the prober would measure itself); what they were answered is added to
    ``record`` after."""
    process = subprocess.Popen(
        [sys.executable, "-m", __name__, url],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        env={**os.environ, "AD_NOISY_TOKEN": token},
    )
    assert process.stdin is not None and process.stdout is not None
    try:
        if process.stdout.readline() != b"started\n":
            raise RuntimeError("the noisy neighbour did not start")
        yield
    finally:
        process.stdin.close()
        answered = json.loads(process.stdout.readline() or b"{}")
        process.wait(timeout=180)
        record.answers.update(answered.get("answers", {}))
        record.breaches.extend(answered.get("breaches", []))


def run_attacks(attacks: list[Attack], until: Callable[[], object]) -> Record:
    """Run ``attacks`` in threads of their own until ``until`` returns; what they were
    answered."""
    record = Record()
    stop = threading.Event()
    threads = [
        threading.Thread(target=_guarded, args=(attack, stop, record), daemon=True)
        for attack in attacks
    ]
    for thread in threads:
        thread.start()
    try:
        until()
    finally:
        stop.set()
        for thread in threads:
            thread.join(timeout=180)
    return record


def _guarded(attack: Attack, stop: threading.Event, record: Record) -> None:
    try:
        attack(stop, record)
    except Exception as error:  # an attack that broke is recorded, never raised in a thread
        record.saw("attack error", f"{type(error).__name__}: {error}"[:200])


def ordinary_studies(http: httpx.Client, trials: int) -> tuple[int, int]:
    """Bob's two studies: the worked one (a real worker serves ``ORDINARY_TASK``) and the
    probed one (the probe leases ``PROBE_TASK``). Their ids."""
    box = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
    ids = []
    for name, task in (("ordinary", ORDINARY_TASK), ("probed", PROBE_TASK)):
        answer = http.post(
            "/api/v1/studies",
            json={
                "name": name,
                "space": box,
                "proposer": {"name": "random"},
                "task": {"name": task, "external": True},
                "max_trials": trials,
            },
        )
        answer.raise_for_status()
        ids.append(int(answer.json()["id"]))
    return ids[0], ids[1]


@dataclass
class Probes:
    """Seconds a read and a lease of the ordinary user's studies took, in each kind of
    block."""

    reads: dict[str, list[float]] = field(default_factory=lambda: {"quiet": [], "noisy": []})
    leases: dict[str, list[float]] = field(default_factory=lambda: {"quiet": [], "noisy": []})
    failures: list[str] = field(default_factory=list)

    def ratio(self, what: str) -> float:
        """The noisy median over the quiet median of ``reads`` or ``leases``."""
        samples = getattr(self, what)
        return statistics.median(samples["noisy"]) / statistics.median(samples["quiet"])


def probe(
    bob: httpx.Client, worker: httpx.Client, study_id: int, block: str, probes: Probes
) -> None:
    """One read of bob's worked study, one lease and tell of his probed study, timed."""
    started = time.perf_counter()
    read = bob.get(f"/api/v1/studies/{study_id}")
    read_s = time.perf_counter() - started
    started = time.perf_counter()
    lease = worker.post("/api/v1/jobs/lease", json={"worker_id": "probe", "tasks": [PROBE_TASK]})
    lease_s = time.perf_counter() - started
    if read.status_code != 200 or lease.status_code != 200:
        probes.failures.append(f"{block}: read {read.status_code}, lease {lease.status_code}")
        return
    probes.reads[block].append(read_s)
    probes.leases[block].append(lease_s)
    job = lease.json()
    told = worker.post(
        f"/api/v1/trials/{job['trial_id']}/tell",
        json={"value": job["params"]["x"], "worker_id": "probe"},
    )
    if told.status_code != 200:
        probes.failures.append(f"{block}: tell {told.status_code} {told.text[:200]}")


def measure(
    bob: httpx.Client,
    worker: httpx.Client,
    studies: tuple[int, int],
    url: str,
    token: str,
    *,
    blocks: int = 3,
    per_block: int = 20,
    ramp_seconds: float = 1.5,
) -> tuple[Probes, Record]:
    """Alternate quiet and noisy blocks of ``per_block`` probes each; in a noisy block the
    user of ``token`` attacks (:func:`noise`), and its probes start after the attacks
    have run ``ramp_seconds`` (their children computing, their uploads past the
    quota)."""
    worked, _ = studies
    probes, record = Probes(), Record()
    for _ in range(2):  # the routes' first calls (imports, the study's config)
        probe(bob, worker, worked, "quiet", Probes())
    for _ in range(blocks):
        for _ in range(per_block):
            probe(bob, worker, worked, "quiet", probes)
        with noise(url, token, record):
            time.sleep(ramp_seconds)
            for _ in range(per_block):
                probe(bob, worker, worked, "noisy", probes)
    return probes, record


def main() -> None:
    """``python -m adclient.testing.neighbours URL`` (the token in ``AD_NOISY_TOKEN``):
    the attacks until standard input closes, then one JSON line of what they were
    answered."""
    url, token = sys.argv[1], os.environ["AD_NOISY_TOKEN"]
    # the lowest CPU priority: the noisy user's client is another machine's cost, not
    # the server's; on one machine it would take the server's core and be measured
    os.nice(19)
    print("started", flush=True)
    record = run_attacks(worst_of_issue_58(url, token), sys.stdin.read)
    print(json.dumps({"answers": dict(record.answers), "breaches": record.breaches}), flush=True)


if __name__ == "__main__":
    main()

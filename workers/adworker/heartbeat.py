"""A job's lease kept alive from a background thread (see :mod:`adworker.worker`)."""

from __future__ import annotations

import logging
import threading
from datetime import UTC, datetime

from adclient.client import Client
from adclient.errors import ApiError, Conflict, Forbidden, NotFound, Unauthorized
from adclient.schemas import Job

log = logging.getLogger("adworker")


class Heartbeat:
    """Extends one job's lease from a background thread until stopped or lost."""

    def __init__(self, client: Client, job: Job, worker_id: str) -> None:
        self.client = client
        self.job = job
        self.worker_id = worker_id
        self.lost = threading.Event()
        self.reason = ""
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._run, name=f"heartbeat-{job.trial_id}", daemon=True
        )

    def _interval(self, expires_at: datetime) -> float:
        remaining = (expires_at - datetime.now(UTC)).total_seconds()
        if not 0 < remaining < 24 * 3600:  # clock skew or nonsense: a safe default
            remaining = 15.0
        return max(0.2, min(remaining / 3, 20.0))

    def _run(self) -> None:
        interval = self._interval(self.job.lease_expires_at)
        while not self._stop.wait(interval):
            try:
                answer = self.client.heartbeat(self.job.trial_id, self.worker_id)
            except (Conflict, NotFound) as exc:
                self.reason = f"lease lost: {exc}"
                self.lost.set()
                return
            except (Unauthorized, Forbidden) as exc:
                self.reason = f"heartbeat refused: {exc}"
                self.lost.set()
                return
            except ApiError as exc:
                log.warning("trial %s: heartbeat failed (%s); retrying", self.job.trial_id, exc)
                interval = max(0.2, interval / 2)
                continue
            interval = self._interval(answer.lease_expires_at)

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

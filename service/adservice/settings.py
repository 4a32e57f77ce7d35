"""Server settings from the environment (prefix ``AD_``), read through one cached getter."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field, FilePath, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="AD_", extra="ignore")

    database_url: str = "sqlite:///./activedesign.db"
    artifact_dir: Path | None = None
    """Artifact folder; default: ``artifacts`` beside a SQLite file, else ./artifacts."""
    lease_seconds: float = 60.0
    unserved_seconds: float = Field(default=60.0, ge=0)
    """A running managed study that no recently seen worker serves and that has been
    idle this long is flagged ``unserved`` (the dashboard's warning)."""
    proposal_threads: int | None = Field(default=None, ge=1)
    """Threads that compute model-based proposals, apart from the ones serving requests;
    None: one per core this process may use."""
    ask_seconds: float | None = Field(default=30.0, gt=0)
    """A model-based ask's time budget: past it the search stops at its best candidates
    so far and the rest of the batch are Sobol points, said in their info. None: none."""
    ask_memory_mb: float | None = Field(default=1024.0, gt=0)
    """The memory one ask may take by its estimate: a study whose options, or an ask
    whose count, would exceed it is refused (422 naming it). None: no limit."""
    ask_gpu_memory_share: float = Field(default=0.5, gt=0, le=1)
    """An ask on cuda may take the larger of ``ask_memory_mb`` and this share of the GPU's
    memory (``memory.device_budget``): a GPU is not held to a CPU budget."""
    proposal_backoff_seconds: float = Field(default=5.0, gt=0)
    """After a study's proposal fails, workers' leases skip the study this long, doubled
    with each failure in a row up to ``proposal_backoff_max_seconds``; a success resets it."""
    proposal_backoff_max_seconds: float = Field(default=600.0, gt=0)
    expand_threads: int = Field(default=2, ge=1)
    """Threads that expand users' templates (study creation, a template study's new
    trials, a URDF read of a trial stored before URDFs were), apart from the ones
    serving requests: each runs one expanding child process at a time."""
    expand_per_owner: int = Field(default=8, ge=1)
    """Of the expansion threads and places, what one study owner's expansions may hold
    (its creations, asks and its studies' leases): past this many running or waiting,
    429 with Retry-After (a lease serves another study); and they run on all but one of
    the threads at most."""
    expand_queue: int = Field(default=16, ge=0)
    """Expansions that may wait for one of those threads; past them a request that
    needs one is answered 503 with Retry-After, and nothing is stored."""

    # Template studies' URDFs (issue 58): the bytes they store, what a lease waits for.
    max_urdf_bytes: int = Field(default=2_000_000, ge=1, le=2_000_000)
    """The largest URDF a template trial's expansion may be (bytes; past it the trial is
    failed, naming it): at most the SDK's and workers' own (``MAX_URDF_BYTES``)."""
    max_ask_urdf_bytes: int = Field(default=32_000_000, ge=1)
    """The bytes of the URDFs one ask (or one lease's proposal, or one enqueue) of a
    template study adds together; a trial past it is failed (an enqueue refused)."""
    max_study_urdf_bytes: int = Field(default=256_000_000, ge=1)
    """The bytes of the URDFs one template study may store; once it does, its asks are
    refused (409) and leases skip it, and the last trials that would pass it fail."""
    lease_expand_seconds: float = Field(default=5.0, gt=0)
    """How long a worker's lease waits for the expansion of a template study's new
    trial; past it the lease serves another study, the expansion goes on in the
    background (the trial back in the queue), and the study backs off as after a failed
    proposal, as it does after an expansion that fails."""

    # Study creation (issue 58): a design space's representation is computed in a child
    # process with budgets (adservice.creations).
    create_processes: int = Field(default=2, ge=1)
    """Child processes that check new design spaces at once (their representation:
    structure similarity, fusion, MDS), at the lowest CPU priority, apart from the
    processes and threads serving requests."""
    create_queue: int = Field(default=16, ge=0)
    """Creations that may wait for one of those processes; past them a creation is
    answered 503 with Retry-After, and nothing is stored."""
    create_per_owner: int = Field(default=4, ge=1)
    """Of those processes and places, what one study owner's creations may hold: past
    this many running or waiting, its creation is a 429 with Retry-After (others still
    find places); and its creations run on all but one of the processes at most, so
    another owner's always finds one within one creation's time."""
    create_seconds: float = Field(default=30.0, gt=0, le=86_400)
    """How long one creation's child may run (its CPU time is held to it too); past it
    the child is killed and the creation is a 422 naming this setting. A space whose
    structures' similarity alone could not fit in it (by the bound on its steps) is
    refused at once."""
    create_memory_mb: float | None = Field(default=1024.0, gt=0)
    """The memory a creation's child may map beyond what it starts with (a fork of the
    server); past it the creation is a 422 naming this setting. None: no limit."""
    shutdown_seconds: float = Field(default=10.0, ge=1, le=3600)
    """SIGTERM or SIGINT ends the server within this long: requests in flight get
    three quarters of it to finish, then are cancelled (creations' children killed,
    nothing half-stored), and past it the process exits whatever is left."""

    # Per-token request rates (adservice.rates): user and reader tokens only.
    token_requests_per_second: float | None = Field(default=100.0, gt=0)
    """Requests a second one user or reader token may send (bursts of
    ``token_request_burst``); past it a request is answered 429 with Retry-After before
    its body is read. None: no limit."""
    token_request_burst: int = Field(default=400, ge=1)
    token_creations_per_minute: float | None = Field(default=60.0, gt=0)
    """Study creations a minute one user token may send (bursts of
    ``token_creation_burst``), within its request rate; past it 429. None: no limit."""
    token_creation_burst: int = Field(default=30, ge=1)

    sweep_seconds: float = 2.0
    """How often expired leases are returned to the queue in the background."""
    max_body_bytes: int = 1_000_000
    max_artifact_bytes: int = 16_000_000
    max_artifacts_per_trial: int = 32
    """How many artifacts one trial may have (a re-upload of a name replaces it)."""
    max_trial_artifact_bytes: int = 64_000_000
    """The bytes all artifacts of one trial may take together."""

    # Storage per owner (issue 58).
    owner_storage_bytes: int | None = Field(default=20_000_000_000, ge=0)
    """The bytes one owner's studies may store: their trials' artifacts and template
    URDFs together (studies without an owner count as one owner). At it, an upload is
    413, and no new trial is made for the owner: its ask or enqueue is 409 and workers'
    leases skip its studies. None: no quota."""
    session_hours: float = 12.0
    """How long a dashboard sign-in lasts."""
    cors_origins: list[str] = []
    """Other web origins allowed to call the API from a browser; none by default."""
    allowed_hosts: list[str] | None = None
    """``Host`` headers served (DNS rebinding defence); "*" allows any. None: see
    :meth:`resolved_allowed_hosts`."""
    public_url: str | None = None
    auth: bool | None = None
    """Require bearer tokens. None: decided by ``adserver`` from the bind address (off on
    loopback, on elsewhere); an app built in-process without it runs open."""
    host: str = "127.0.0.1"
    port: int = 8000
    log_level: Literal["critical", "error", "warning", "info", "debug", "trace"] = "info"
    torch_threads: int = 1
    """torch's intra-op threads in a model-based ask (one: requests run side by side)."""
    proposer_device: Literal["cpu", "cuda"] = "cpu"
    """The torch device of qEI's model fits (a study's ``device`` option overrides it).
    cuda needs a GPU and a CUDA build of torch: ``adserver`` refuses to start without."""
    max_header_bytes: int = 65_536
    """A request line and headers longer than this: 431, and the connection is closed."""
    header_timeout: float = 10.0
    """Seconds from a request's first byte (or a new connection) to the end of its headers;
    past it the connection is closed (408 when part of a request came)."""
    body_timeout: float = 60.0
    """Seconds a request body may take to arrive, counted from the end of its headers
    (408 past it): 16 MB artifacts need about 270 kB/s."""
    keep_alive_timeout: float = 5.0
    """Seconds an idle keep-alive connection stays open between requests."""
    max_connections: int | None = None
    """Open connections (and requests) beyond which uvicorn answers 503; None: no cap.
    Idle and slow connections count too, so a cap turns a slowloris into a refusal of
    service: the header timeout is the defence, the cap only bounds memory."""
    ssl_certfile: FilePath | None = None
    """PEM certificate (chain) for HTTPS; ``ssl_keyfile`` too unless it holds the key."""
    ssl_keyfile: FilePath | None = None

    @model_validator(mode="after")
    def _keyfile_needs_certfile(self) -> Settings:
        if self.ssl_keyfile is not None and self.ssl_certfile is None:
            raise ValueError("ssl_keyfile is set but ssl_certfile is not")
        return self

    def resolved_allowed_hosts(self) -> list[str]:
        """The ``Host`` names served: ``allowed_hosts`` if set; else any when bound to every
        interface (auth is on there), otherwise the bound address, the loopback names and
        the host of ``public_url`` (what a DNS-rebinding page cannot send)."""
        if self.allowed_hosts is not None:
            return self.allowed_hosts
        if self.host in ("0.0.0.0", "::", ""):
            return ["*"]
        hosts = {self.host, "localhost", "127.0.0.1", "::1", "[::1]"}
        if self.public_url:
            from urllib.parse import urlsplit

            public = urlsplit(self.public_url).hostname
            if public:
                hosts.add(public)
        return sorted(hosts)

    def resolved_artifact_dir(self) -> Path:
        if self.artifact_dir is not None:
            return self.artifact_dir
        prefix = "sqlite:///"
        if self.database_url.startswith(prefix) and ":memory:" not in self.database_url:
            return Path(self.database_url[len(prefix) :]).resolve().parent / "artifacts"
        return Path("artifacts").resolve()


@lru_cache
def get_settings() -> Settings:
    return Settings()

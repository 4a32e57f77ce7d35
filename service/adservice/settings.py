"""Server settings from the environment (prefix ``AD_``), read through one cached getter."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="AD_", extra="ignore")

    database_url: str = "sqlite:///./activedesign.db"
    artifact_dir: Path | None = None
    """Artifact folder; default: ``artifacts`` beside a SQLite file, else ./artifacts."""
    lease_seconds: float = 60.0
    sweep_seconds: float = 2.0
    """How often expired leases are returned to the queue in the background."""
    max_body_bytes: int = 1_000_000
    max_artifact_bytes: int = 16_000_000
    max_artifacts_per_trial: int = 32
    """How many artifacts one trial may have (a re-upload of a name replaces it)."""
    max_trial_artifact_bytes: int = 64_000_000
    """The bytes all artifacts of one trial may take together."""
    session_hours: float = 12.0
    """How long a dashboard sign-in lasts."""
    cors_origins: list[str] = []
    """Other web origins allowed to call the API from a browser; none by default."""
    allowed_hosts: list[str] | None = None
    """``Host`` headers served (DNS rebinding defence). None: ``adserver`` allows its bind
    address, loopback names and the host of ``public_url``; "*" allows any."""
    public_url: str | None = None
    auth: bool | None = None
    """Require bearer tokens. None: decided by ``adserver`` from the bind address (off on
    loopback, on elsewhere); an app built in-process without it runs open."""

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

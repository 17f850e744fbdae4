"""Service settings: ``PEDNAV_*`` environment variables, validated when the app starts (fail fast)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict
from sqlalchemy.engine import make_url

__all__ = ["MIN_PROFILE_BYTES", "Settings", "SettingsError", "load_settings"]

MIN_PROFILE_BYTES = 256 * 1024
"""Smallest ``max_profile_bytes``: a profile the engine hands out (and a client may put back) stays below it."""


class Settings(BaseSettings):
    """Configuration of one server process.

    Parameters
    ----------
    database_url : str
        Any SQLAlchemy URL; default a SQLite file ``pednav.db`` in the current directory.
    db_schema : str or None
        PostgreSQL schema holding the tables (tests use a unique one per run); ``None`` = default.
    max_body_bytes : int
        Largest accepted request body [bytes]; larger bodies get HTTP 413.
    max_samples_per_stream : int
        Largest number of samples of one stream in one batch; more gets HTTP 413.
    engine_mode : str
        Mode handed to each session's engine (``auto``, ``zupt``, ``pdr``).
    migrate_on_startup : bool
        Run Alembic migrations to ``head`` when the app is created.
    engine_cache_size : int
        Engines kept in memory between batches (their state is still persisted: every ``state_every`` batches,
        the raw batches with every upload). It should hold every active session routed to the helper: a miss
        restores the engine from the database (``pednav bench load``, 700 devices on one helper: 2.2 ms of
        helper CPU per batch with 512, 0.9 ms with 2048). An engine takes 0.1-0.6 MB (30 s to 7 min of a
        synthetic day, ``auto``); only active sessions fill the cache.
    state_every : int
        A session's engine state is stored as a checkpoint every this many batch uploads [batches]
        (``PEDNAV_STATE_EVERY``); every raw batch is still stored before its upload is answered, and a restore
        replays the stored batches after the last checkpoint (exact: the engine is chunk invariant). 1 = after
        every batch. Larger saves serialising and writing the ~30 kB state per batch at the price of up to
        ``state_every - 1`` batches replayed when an engine is restored (``pednav bench engine``).
    engine_processes : int
        Helper processes per server process that run the navigation engines (0 = in the server process).
    engine_warmup : bool
        Compile or load the engine's kernels when the server starts and report ready on ``/healthz`` only then;
        uploads before are refused with 503 ``Retry-After`` (nothing stored). False: the first upload compiles.
    ingest_threads : int
        Worker threads of one process that handle batch uploads (uploads in flight; a thread waiting for the
        engine helper or the commit holds no GIL).
    sensorlogger_hold_s : float
        Sensor Logger pushes may arrive out of order: samples are held back this long [s] before being
        fed to the engine in time order.
    token_ttl_s : int
        Lifetime of newly minted tokens [s] (API and CLI); 0 = they never expire. Default 30 days.
    token_max_ttl_s : int
        Longest lifetime a client may ask for when minting a token [s].
    rate_limit_per_s : float
        Sustained requests per second allowed per user, shared by all of the user's tokens (per server process);
        0 = no limit.
    rate_limit_burst : int
        Requests a user may make at once after being idle.
    max_tokens_per_user : int
        Live (unexpired, unrevoked) tokens a user may hold; ``POST /v1/tokens`` beyond it is refused with 409
        until the user revokes one (``DELETE /v1/tokens/{id}``) or one expires. As many revoked or expired
        tokens are kept per user (listed by ``GET /v1/tokens``); older ones are deleted when a token is minted,
        so the tokens table holds at most about twice this per user. The admin CLI (``pednav admin token``)
        is not held to it.
    auth_failures_per_s : float
        Failed authentications (401) allowed per client address and second on average, per server process; past
        them every request with a token gets 429 before its token is looked up. 0 = no limit.
    auth_failures_burst : int
        Failed authentications a client may make at once.
    max_profile_bytes : int
        Largest calibration profile a client may store (``PUT /v1/profiles/{behaviour}``), as compact JSON
        [bytes]; larger gets HTTP 413. At least 256 kB: a profile the engine hands out reaches about 180 kB at its
        bounds (300 calibration pairs per behaviour; 300 compass rows and dip stances, 600 swing samples), and a
        client may put it back. ``max_body_bytes`` still bounds the whole body.
    max_profile_versions : int
        Versions of a user's profile kept per behaviour (the newest; every replace, reset and session close adds
        one, and the older ones are deleted beyond this).
    cors_origins : str
        Origins allowed to call the API from a browser page served elsewhere (CORS), comma-separated, e.g.
        ``https://app.example.org,http://localhost:5173``; ``*`` = any origin; empty (default) = CORS off (the web
        viewer at ``/app`` is served by the API itself and needs none).
    sensorlogger_idle_close_s : float
        A Sensor Logger session that received no push for this long [s] is flushed and closed (the app sends
        nothing when its recording stops); 0 = never.
    anchor_max_accuracy_m : float
        A phone's location fix anchors a session when its horizontal accuracy is at most this [m] (the first such
        fix; ``models.geo.anchor_from_fixes``).
    map_tile_url : str
        Map tiles of the web viewer for anchored sessions (a Leaflet URL template); default OpenStreetMap's
        (mind its tile usage policy for heavy use); empty = never tiles (a metric grid). The viewer also falls
        back to the grid when the browser is offline or a tile fails to load.
    map_tile_attribution : str
        The attribution the tiles' licence asks for, shown on the map.
    log_requests : bool
        Log one structured line per request (method, path, status, duration; logger ``pednav.access``).
    pg_one_statement_writes : bool
        PostgreSQL: write an upload (session update, raw batch, positions, events) as one atomic statement in
        autocommit mode, on a driver connection (2 round trips per upload: token and session read, write);
        false: the ORM transaction of ``server.ingest.apply_batch``.
    """

    model_config = SettingsConfigDict(env_prefix="PEDNAV_", extra="ignore")

    database_url: str = "sqlite:///pednav.db"
    db_schema: str | None = None
    max_body_bytes: int = Field(default=4_000_000, gt=0)
    max_samples_per_stream: int = Field(default=60_000, gt=0)
    engine_mode: Literal["auto", "zupt", "pdr"] = "auto"
    migrate_on_startup: bool = True
    engine_cache_size: int = Field(default=2048, ge=0)
    state_every: int = Field(default=4, ge=1, le=1000)
    sensorlogger_hold_s: float = Field(default=2.0, ge=0.0)
    ingest_threads: int = Field(default=16, ge=1, le=64)
    engine_processes: int = Field(default=1, ge=0, le=64)
    engine_warmup: bool = True
    token_ttl_s: int = Field(default=30 * 86_400, ge=0)
    token_max_ttl_s: int = Field(default=365 * 86_400, ge=60)
    rate_limit_per_s: float = Field(default=50.0, ge=0.0, allow_inf_nan=False)
    rate_limit_burst: int = Field(default=200, ge=1)
    max_tokens_per_user: int = Field(default=20, ge=1, le=10_000)
    auth_failures_per_s: float = Field(default=2.0, ge=0.0, allow_inf_nan=False)
    auth_failures_burst: int = Field(default=50, ge=1)
    max_profile_bytes: int = Field(default=512 * 1024, ge=MIN_PROFILE_BYTES)
    max_profile_versions: int = Field(default=50, ge=1, le=100_000)
    pg_one_statement_writes: bool = True
    cors_origins: str = ""
    sensorlogger_idle_close_s: float = Field(default=300.0, ge=0.0, allow_inf_nan=False)
    anchor_max_accuracy_m: float = Field(default=25.0, gt=0.0, allow_inf_nan=False)  # models.geo.GOOD_FIX_ACCURACY_M
    log_requests: bool = True
    map_tile_url: str = "https://tile.openstreetmap.org/{z}/{x}/{y}.png"
    map_tile_attribution: str = "&copy; OpenStreetMap contributors"

    def cors_origin_list(self) -> list[str]:
        """``cors_origins`` as a list (empty: CORS off)."""
        return [o.strip() for o in self.cors_origins.split(",") if o.strip()]

    @model_validator(mode="after")
    def _check_limits(self) -> Settings:
        if 0 < self.token_ttl_s < 60:
            raise ValueError(f"PEDNAV_TOKEN_TTL_S={self.token_ttl_s}: use 0 (tokens never expire) or at least 60 s")
        if self.token_ttl_s > self.token_max_ttl_s:
            raise ValueError(
                f"PEDNAV_TOKEN_TTL_S={self.token_ttl_s} exceeds PEDNAV_TOKEN_MAX_TTL_S={self.token_max_ttl_s}"
            )
        return self

    @field_validator("database_url")
    @classmethod
    def _check_url(cls, v: str) -> str:
        try:
            url = make_url(v)
        except Exception as exc:  # noqa: BLE001 - any parse failure is a configuration error
            raise ValueError(f"PEDNAV_DATABASE_URL is not a SQLAlchemy URL: {exc}") from exc
        if url.get_backend_name() not in ("sqlite", "postgresql"):
            raise ValueError(f"unsupported database backend {url.get_backend_name()!r} (sqlite or postgresql)")
        return v

    @field_validator("cors_origins")
    @classmethod
    def _check_cors(cls, v: str) -> str:
        for o in (x.strip() for x in v.split(",")):
            if o and o != "*" and not (o.startswith(("http://", "https://")) and "/" not in o.split("://", 1)[1]):
                raise ValueError(f"PEDNAV_CORS_ORIGINS: {o!r} is not an origin (scheme://host[:port], no path) or *")
        return v

    @field_validator("db_schema")
    @classmethod
    def _check_schema(cls, v: str | None) -> str | None:
        if v is not None and not v.replace("_", "").isalnum():
            raise ValueError("db_schema must be alphanumeric/underscore")
        return v


class SettingsError(ValueError):
    """Invalid ``PEDNAV_*`` configuration; the message names each variable and its problem."""


def load_settings(**overrides: object) -> Settings:
    """``Settings()`` from the environment (plus ``overrides``), failing with one readable message."""
    from pydantic import ValidationError

    try:
        return Settings(**overrides)  # type: ignore[arg-type]
    except ValidationError as exc:
        parts = []
        for e in exc.errors():
            loc = ".".join(str(x) for x in e.get("loc", ()))
            msg = str(e.get("msg", "")).removeprefix("Value error, ")
            parts.append(f"PEDNAV_{loc.upper()}: {msg}" if loc else msg)
        raise SettingsError("invalid configuration: " + "; ".join(parts)) from None

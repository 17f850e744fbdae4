"""Work that is not per request, as jobs on Dramatiq over Redis: re-processing stored sessions with a new
engine release (and, built on it, evaluating a configuration over many users' recordings).

The API workers stay stateless; PostgreSQL is the store of record; Redis carries the job messages. A job is a
session id: any worker process on any machine with the same ``PEDNAV_DATABASE_URL`` takes it, re-runs the
session's stored raw batches through its engine (:func:`server.reprocess.reprocess_session`: one write
transaction guarded by the session's version, so a batch that arrives meanwhile makes the job fail with a
conflict and Dramatiq retries it) and counts the outcome in Redis. Messages are acknowledged after the job ran
(Dramatiq's default), so a worker killed mid-job leaves its message to another worker.

Why Dramatiq (measured with ``pednav bench jobs``; docs/deployment.md has the figures): over Redis it scaled
re-processing like the other engines measured here, starts in a second, acknowledges late by default, retries
with backoff, and adds two small packages (dramatiq, redis); Dask distributed keeps its task graph in a
scheduler's memory (a scheduler restart loses the queue); Celery acknowledges early by default and brings
kombu/billiard/vine; Ray is a cluster runtime of its own (a large install) for a job that is a loop over session
ids.

Start workers with ``dramatiq server.jobs_worker --processes N --threads 1`` (``PEDNAV_REDIS_URL``,
``PEDNAV_DATABASE_URL``, ``PEDNAV_DB_SCHEMA`` as for the server); enqueue with :func:`enqueue_reprocess`
(``pednav admin reprocess`` uses it).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

__all__ = ["JOB_QUEUE", "JobOutcome", "declare", "enqueue_reprocess", "make_broker", "reprocess_job", "outcomes"]

JOB_QUEUE = "pednav"
_COUNTS = "pednav:jobs:{run}"  # Redis hash of outcome counts per run id


@dataclass(frozen=True)
class JobOutcome:
    """Counts of one run of jobs (a run id groups the jobs enqueued together)."""

    done: int
    identical: int
    changed: int
    conflicts: int
    missing: int
    worker_pids: frozenset[int] = frozenset()


class _Worker:
    """Per worker process: the database engine and engine host, made on the first job."""

    state: dict[str, Any] = {}

    @classmethod
    def get(cls) -> tuple[Any, Any]:
        if not cls.state:
            from server.db import make_engine, make_sessionmaker
            from server.ingest import EngineHost
            from server.settings import load_settings

            settings = load_settings()
            eng = make_engine(settings)
            cls.state = {"sm": make_sessionmaker(eng), "host": EngineHost(0, engine_processes=0)}
        return cls.state["sm"], cls.state["host"]

    @classmethod
    def redis(cls, url: str) -> Any:
        """This process's Redis client of ``url`` (one connection pool per process, not one per job)."""
        import redis

        clients = cls.state.setdefault("redis", {})
        if url not in clients:
            clients[url] = redis.Redis.from_url(url)
        return clients[url]


def reprocess_job(session_id: int, run: str, engine_mode: str | None = None, dry_run: bool = False,
                  redis_url: str | None = None) -> str:
    """Re-process one stored session with this worker's engine; counts the outcome under ``run`` in Redis and
    returns it (``identical``, ``changed``, ``missing``). A :class:`server.reprocess.ReprocessConflict` is raised
    (Dramatiq retries the job) after being counted as a conflict."""
    from server.models import TrackSession, User
    from server.reprocess import ReprocessConflict, reprocess_session

    sm, host = _Worker.get()
    r = _Worker.redis(redis_url or os.environ.get("PEDNAV_REDIS_URL", "redis://127.0.0.1:6379/0"))
    key = _COUNTS.format(run=run)
    with sm() as db:
        sess = db.get(TrackSession, session_id)
        user = db.get(User, sess.user_id) if sess is not None else None
        db.rollback()
        if user is None:
            r.hincrby(key, "missing", 1)
            r.hincrby(key, "done", 1)
            return "missing"
        try:
            res = reprocess_session(db, host, user, session_id, engine_mode, dry_run)
        except ReprocessConflict:
            r.hincrby(key, "conflicts", 1)
            raise
    outcome = "missing" if res is None else ("identical" if res.identical else "changed")
    r.sadd(key + ":pids", os.getpid())  # which worker processes took the run's jobs
    r.hincrby(key, outcome, 1)
    r.hincrby(key, "done", 1)
    return outcome


def make_broker(redis_url: str | None = None) -> Any:
    """A Dramatiq Redis broker for ``redis_url`` (default ``PEDNAV_REDIS_URL`` or redis://127.0.0.1:6379/0)."""
    from dramatiq.brokers.redis import RedisBroker

    return RedisBroker(url=redis_url or os.environ.get("PEDNAV_REDIS_URL", "redis://127.0.0.1:6379/0"))


def declare(broker: Any) -> Any:
    """The Dramatiq actor of :func:`reprocess_job` on ``broker`` (retries with backoff, acknowledged after it ran)."""
    import dramatiq

    return dramatiq.actor(reprocess_job, broker=broker, actor_name="reprocess_job", queue_name=JOB_QUEUE,
                          max_retries=5, min_backoff=1000, time_limit=30 * 60 * 1000)


def enqueue_reprocess(actor: Any, session_ids: list[int], run: str, engine_mode: str | None = None,
                      dry_run: bool = False, redis_url: str | None = None) -> None:
    """One job per session id, all counted under ``run``."""
    for sid in session_ids:
        actor.send(sid, run, engine_mode, dry_run, redis_url)


def outcomes(run: str, redis_url: str | None = None) -> JobOutcome:
    """The counts of ``run`` so far."""
    import redis

    r = redis.Redis.from_url(redis_url or os.environ.get("PEDNAV_REDIS_URL", "redis://127.0.0.1:6379/0"))
    key = _COUNTS.format(run=run)
    h = {k.decode(): int(v) for k, v in r.hgetall(key).items()}
    return JobOutcome(h.get("done", 0), h.get("identical", 0), h.get("changed", 0), h.get("conflicts", 0),
                      h.get("missing", 0), frozenset(int(p) for p in r.smembers(key + ":pids")))

"""Entry module of a job worker process: ``dramatiq server.jobs_worker --processes N --threads 1``.

Importing it sets Dramatiq's broker from ``PEDNAV_REDIS_URL`` and declares the actors of :mod:`server.jobs`
(that is what a Dramatiq worker module is for; nothing else imports it)."""

from __future__ import annotations

import dramatiq

from server.jobs import declare, make_broker

__all__ = ["broker", "reprocess"]

broker = make_broker()
dramatiq.set_broker(broker)
reprocess = declare(broker)

"""The contract is the code: schemathesis generates requests for every route of the published OpenAPI document
(bounded examples per route, SQLite and PostgreSQL) and checks that no answer is a 5xx and that every answer --
status code, content type, headers and body -- is the one the document publishes.

``PEDNAV_CONTRACT_EXAMPLES`` sets the examples per route (default 25; CI's bound); ``pednav``'s own tests of each
refusal live beside this file.
"""

from __future__ import annotations

import os
import time
import uuid
from collections.abc import Iterator
from typing import Any

import pytest

schemathesis = pytest.importorskip("schemathesis", reason="schemathesis (a test dependency) is not installed")

from hypothesis import HealthCheck, given  # noqa: E402
from hypothesis import settings as hsettings  # noqa: E402
from schemathesis import checks as st_checks  # noqa: E402

from server import crud  # noqa: E402
from tests.server.conftest import app_with  # noqa: E402

EXAMPLES = int(os.environ.get("PEDNAV_CONTRACT_EXAMPLES", "25"))
CHECKS = [st_checks.not_a_server_error, st_checks.status_code_conformance, st_checks.content_type_conformance,
          st_checks.response_headers_conformance, st_checks.response_schema_conformance]


def _packable(v: Any) -> Any:
    """``v`` with integers beyond msgpack's 64 bits as floats (msgpack cannot carry them; the server then refuses
    the float where it wants an integer, which is what such a request tests)."""
    if isinstance(v, bool):
        return v
    if isinstance(v, int) and not -(2**63) <= v < 2**64:
        return float(v)
    if isinstance(v, dict):
        return {_packable(k): _packable(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_packable(x) for x in v]
    return v


@schemathesis.serializer("application/msgpack")
def _msgpack(_ctx: Any, value: Any) -> bytes:
    import msgpack

    return msgpack.packb(_packable(value), use_bin_type=True)


@pytest.fixture(scope="module")
def contract_app(settings, app) -> Iterator[Any]:  # type: ignore[no-untyped-def]  # app: the migrated database
    # no per-user rate limit and no failed-authentication guard: the generator sends hundreds of requests a second
    with app_with(settings, rate_limit_per_s=0.0, auth_failures_per_s=0.0) as (app, _client):
        with app.state.sessionmaker() as db:
            user, token = crud.create_user(db, f"contract-{uuid.uuid4().hex[:8]}", is_admin=True, ttl_s=None)
            db.commit()
            app.state.contract_user = user
        app.state.contract_token = token
        yield app


def _token_for(app: Any, case: Any) -> str:
    """The admin token, or a throwaway token of the same user for the routes that revoke the token they get."""
    if case.method.upper() == "DELETE" and case.path.startswith("/v1/tokens"):
        with app.state.sessionmaker() as db:
            tok = crud.issue_token(db, app.state.contract_user, "contract")
            db.commit()
        return tok
    return app.state.contract_token


def _operations(app: Any) -> list[Any]:
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    return [r.ok() for r in schema.get_all_operations()]


def test_every_route_answers_as_published(contract_app) -> None:  # type: ignore[no-untyped-def]
    """Every operation, ``EXAMPLES`` generated requests each (schemathesis's positive and negative data): no 5xx,
    no status code, content type, header or body outside the published document."""
    ops = _operations(contract_app)
    assert len(ops) >= 28
    failures: dict[str, str] = {}
    spent: dict[str, float] = {}
    for op in ops:

        @hsettings(max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), database=None)
        @given(case=op.as_strategy())
        def run(case: Any) -> None:
            headers = dict(case.headers or {})
            headers.setdefault("Authorization", f"Bearer {_token_for(contract_app, case)}")
            case.call_and_validate(headers=headers, checks=CHECKS, timeout=300)  # a loaded CI machine is slow

        t0 = time.perf_counter()
        try:
            run()
        except Exception as exc:  # noqa: BLE001 - collected per operation, reported together
            parts = list(getattr(exc, "exceptions", [exc]))
            failures[op.label] = "\n".join(f"{type(e).__name__}: {str(e)[:1500]}" for e in parts)
        spent[op.label] = time.perf_counter() - t0
    assert not failures, "\n\n".join(f"{k}: {v}" for k, v in failures.items())

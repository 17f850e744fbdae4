"""The published OpenAPI document: what the server answers, as a client developer reads it.

FastAPI's own document said less than the server does: only 200/201/422 per route, a 422 ``detail`` typed as
an array where the server sends one readable string, no request body for the batch upload (whose JSON and
msgpack forms are parsed by hand for speed) and no security entry there, generated operation ids such as
``put_batch_v1_sessions__session_id__batches__seq__put``. :func:`install` makes the app publish instead:

- every refusal the server can give, each with the :class:`server.schemas.ErrorOut` body (``Retry-After`` on
  429 and 503, ``WWW-Authenticate`` on 401);
- the bearer scheme on every protected route (and the ``?token=`` query key on the Sensor Logger push);
- the batch upload's two bodies (:data:`BATCH_JSON_SCHEMA`, :data:`BATCH_MSGPACK_SCHEMA`) and the trajectory's
  three media types;
- operation ids ``<tag>_<function>`` (``batches_put_batch``, ``sessions_start_session``), stable as long as the
  route functions keep their names.

``tests/server/test_contract.py`` runs schemathesis against this document on SQLite and PostgreSQL.
"""

from __future__ import annotations

import re
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import APIRoute

from server.schemas import ErrorOut

__all__ = ["BATCH_JSON_SCHEMA", "BATCH_MSGPACK_SCHEMA", "ERRORS", "install", "operation_id"]

ERRORS: dict[int, str] = {
    400: "The body could not be read as the declared content type (e.g. not UTF-8).",
    401: "Missing, invalid, revoked or expired bearer token, or a token in the query string of a route that "
         "takes none (``WWW-Authenticate: Bearer``).",
    403: "The token's user may not do this (admins only).",
    404: "No such resource of this user (another user's ids are not found either).",
    409: "Conflicts with the resource's state: a batch sequence number that leaves a gap or was used by other "
         "content (``expected_seq``), a closed session, a limit of live tokens, an existing user name, a session "
         "changed while it was re-processed, a GeoJSON export without a geodetic start.",
    413: "Body larger than ``max_body_bytes``, a stream with more than ``max_samples_per_stream`` samples, or a "
         "profile above ``max_profile_bytes``.",
    422: "Invalid input; ``field`` names the part at fault and ``detail`` says what is wrong with it.",
    429: "Rate limit of the user, or too many failed authentications from this client (``Retry-After`` [s]).",
    503: "Nothing of this request was stored: the database stayed busy, the engine's helper process died twice, or "
         "the engines are still being compiled after a fresh install. Send the same request again after "
         "``Retry-After`` [s] (a batch under the same sequence number).",
}

# codes beyond the common ones (401/413/422/429/503 on protected routes, 400 with a body, 404 with a path id)
_EXTRA: dict[str, set[int]] = {
    "auth_create_user": {403, 409},
    "auth_new_token": {409},
    "batches_put_batch": {409},
    "sessions_start_session": {404},
    "sessions_reprocess": {409},
    "trajectories_trajectory": {409},
    "sensorlogger_push": {409, 413},
}

BATCH_JSON_SCHEMA: dict[str, Any] = {
    "title": "BatchJson",
    "type": "object",
    "description": "Samples of one upload; each stream optional, at least one sample in all. Timestamps int64 "
                   "ns, strictly increasing per stream; acc specific force [m/s^2], gyr [rad/s], mag [uT], body "
                   "frame. Gyroscope and magnetometer samples must be after those of the previous batch.",
    "additionalProperties": False,
    "minProperties": 1,
    "properties": {name: {
        "type": "object",
        "required": ["t_ns", "xyz"],
        "additionalProperties": False,
        "properties": {
            "t_ns": {"type": "array", "items": {"type": "integer", "minimum": -(2**63), "maximum": 2**63 - 1}},
            "xyz": {"type": "array", "items": {"type": "array", "items": {"type": "number"}, "minItems": 3,
                                               "maxItems": 3}},
        },
    } for name in ("acc", "gyr", "mag")},
}

_MSGPACK_STREAM: dict[str, Any] = {
    "type": "object",
    "required": ["n", "dtype", "xyz"],
    "additionalProperties": False,
    "properties": {
        "n": {"type": "integer", "minimum": 0, "maximum": 2**31 - 1, "description": "samples"},
        "dtype": {"type": "string", "enum": ["<f4", "<f8"], "description": "little-endian float32 or float64"},
        "xyz": {"type": "string", "format": "binary", "description": "n*3 packed values, row-major"},
        "t0": {"type": "integer", "minimum": -(2**63), "maximum": 2**63 - 1,
               "description": "first timestamp [ns] (with dt)"},
        "dt": {"type": "string", "format": "binary", "description": "n-1 packed <i4 deltas [ns]"},
        "t": {"type": "string", "format": "binary", "description": "n packed <i8 timestamps [ns] (instead of t0/dt)"},
    },
}

BATCH_MSGPACK_SCHEMA: dict[str, Any] = {
    "title": "BatchMsgpack",
    "type": "object",
    "description": "The compact binary form of BatchJson as a msgpack map (server/formats.py): version 1, per "
                   "stream its sample count, packed values and packed timestamps.",
    "required": ["v"],
    "additionalProperties": False,
    "properties": {"v": {"type": "integer", "enum": [1]}, **{name: _MSGPACK_STREAM for name in ("acc", "gyr", "mag")}},
}


def operation_id(route: APIRoute) -> str:
    """``<first tag>_<function name>``: readable, and stable while the route functions keep their names."""
    tag = str(route.tags[0]) if route.tags else "meta"
    return f"{tag}_{route.name}"


def _error_response(code: int) -> dict[str, Any]:
    out: dict[str, Any] = {"description": ERRORS[code],
                           "content": {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorOut"}}}}
    if code in (429, 503):
        out["headers"] = {"Retry-After": {"description": "seconds to wait before sending again",
                                          "schema": {"type": "integer"}}}
    if code == 401:
        out["headers"] = {"WWW-Authenticate": {"schema": {"type": "string"}}}
    return out


def _document(app: FastAPI) -> dict[str, Any]:
    doc = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
    schemas = doc.setdefault("components", {}).setdefault("schemas", {})
    schemas.pop("HTTPValidationError", None)
    schemas.pop("ValidationError", None)
    schemas["ErrorOut"] = ErrorOut.model_json_schema(ref_template="#/components/schemas/{model}")
    schemas["BatchJson"] = BATCH_JSON_SCHEMA
    schemas["BatchMsgpack"] = BATCH_MSGPACK_SCHEMA
    doc["components"]["securitySchemes"] = {
        "HTTPBearer": {"type": "http", "scheme": "bearer", "description": "a token from 'pednav admin create-user' "
                       "or POST /v1/tokens"},
        "QueryToken": {"type": "apiKey", "in": "query", "name": "token",
                       "description": "POST /v1/sensorlogger only (the Sensor Logger app cannot set headers)"},
    }
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            oid = op.get("operationId", "")
            protected = path.startswith("/v1/")
            codes: set[int] = {413, 422, 503}
            if protected:
                codes |= {401, 429}
                op["security"] = [{"HTTPBearer": []}]
            if "requestBody" in op:
                codes.add(400)
            if re.search(r"\{[^}]+\}", path):
                codes.add(404)
            codes |= _EXTRA.get(oid, set())
            responses = op.setdefault("responses", {})
            for code in sorted(codes):
                responses[str(code)] = _error_response(code)
            if oid == "sensorlogger_push":
                op["security"] = [{"HTTPBearer": []}, {"QueryToken": []}]
            if oid == "batches_put_batch":
                op["requestBody"] = {"required": True, "content": {
                    "application/json": {"schema": {"$ref": "#/components/schemas/BatchJson"}},
                    "application/msgpack": {"schema": {"$ref": "#/components/schemas/BatchMsgpack"}},
                }}
                ok = responses["200"]
                ok["headers"] = {
                    "X-Pednav-Replayed": {"description": "true: a retry answered from the store, applied once",
                                          "schema": {"type": "string", "enum": ["true", "false"]}},
                    "Server-Timing": {"description": "server phases [ms]", "schema": {"type": "string"}},
                }
            if oid == "trajectories_trajectory":
                content = responses["200"].setdefault("content", {})
                content["application/geo+json"] = {"schema": {"type": "object", "description": "RFC 7946 "
                                                   "FeatureCollection (format=geojson)"}}
                content["text/csv"] = {"schema": {"type": "string", "description": "format=csv"}}
            if oid == "batches_raw_batch":
                responses["200"]["content"] = {"application/msgpack": {"schema": {
                    "$ref": "#/components/schemas/BatchMsgpack"}}}
    health = doc["paths"].get("/healthz", {}).get("get")
    if health is not None:
        health["responses"]["503"] = {
            "description": "not ready: the engines are still being compiled or loaded (``Retry-After``)",
            "headers": {"Retry-After": {"schema": {"type": "integer"}}},
            "content": {"application/json": {"schema": {"type": "object"}}}}
    return doc


def install(app: FastAPI) -> None:
    """Publish :func:`_document` as the app's OpenAPI document (built once, on first request)."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = _document(app)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]

"""Request (input) and response (output) schemas of the REST API."""

from __future__ import annotations

import math
import re
from datetime import date, datetime
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, computed_field

__all__ = [
    "CONTROL_CHARS",
    "DeviceKind",
    "ErrorOut",
    "Label",
    "check_text",
    "check_user_name",
    "UserCreate",
    "UserOut",
    "TokenCreate",
    "TokenOut",
    "TokenInfoOut",
    "DeviceCreate",
    "DeviceOut",
    "SessionCreate",
    "SessionPatch",
    "SessionOut",
    "SensorConfigOut",
    "PositionOut",
    "EventOut",
    "BatchResponse",
    "ProfileIn",
    "ProfileOut",
    "GaitSummaryOut",
    "SensorLoggerItem",
    "SensorLoggerPush",
    "ReprocessIn",
    "ReprocessOut",
    "DistanceIn",
]

DeviceKind = Literal["foot", "phone", "watch"]
Placement = Literal["foot", "phone-hand", "phone-pocket", "watch"]
BehaviourName = Literal["stand", "walk", "run", "other"]

CONTROL_CHARS = re.compile(r"[\x00-\x1f\x7f]")
"""Characters no name, label or identifier may hold: C0 controls and DEL. PostgreSQL refuses NUL in text (a
device name, token label or Sensor Logger id with one answered HTTP 500), SQLite stored it; the others break
logs and terminals."""


def check_text(v: str) -> str:
    """``v`` itself, or ``ValueError`` naming the first control character and where it is."""
    m = CONTROL_CHARS.search(v)
    if m is not None:
        raise ValueError(f"control character U+{ord(m.group()):04X} at position {m.start()} (not allowed in text)")
    return v


_TEXT_SCHEMA = {"pattern": r"^[^\x00-\x1f\x7f]*$"}  # what check_text takes, published in the schema
Label = Annotated[str, Field(max_length=100, json_schema_extra=_TEXT_SCHEMA), AfterValidator(check_text)]
"""Free text of at most 100 characters (the columns' size) without control characters."""

USER_NAME = re.compile(r"^[A-Za-z0-9_.@-]{1,100}$")


def check_user_name(name: str) -> str:
    """``name`` itself, or ``ValueError`` saying what a user name must be (API and ``pednav admin``)."""
    if not USER_NAME.match(name):
        raise ValueError(f"user name {name!r} must be 1-100 characters of letters, digits, '_', '.', '@' or '-'")
    return name


_ID = {"ge": -(2**31), "le": 2**31 - 1}  # the id columns' range (server.deps.ID_MIN/ID_MAX)


class ErrorOut(BaseModel):
    """Every refusal (4xx) and 503: ``detail`` says what went wrong in one readable line; ``field`` names the
    offending part of the request where there is one (``path.session_id``, ``acc.xyz``, ``body``...)."""

    detail: str
    field: str | None = Field(default=None, description="the request part at fault (422), when there is one")
    problem: str | None = Field(default=None, description="what is wrong with ``field`` (422 from batch checks)")
    errors: list[dict[str, Any]] | None = Field(default=None, description="every validation error: field, problem (422)")
    expected_seq: int | None = Field(default=None, description="the sequence number the session expects next (409)")


class _Out(BaseModel):
    model_config = ConfigDict(from_attributes=True)


class UserCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.@-]+$")
    ttl_s: int | None = Field(default=None, ge=60, description="lifetime of the new user's first token [s], as for "
                              "POST /v1/tokens: at most token_max_ttl_s and the remaining lifetime of the admin's "
                              "token (422 beyond); default: the server's token_ttl_s, ending no later than it")


class UserOut(_Out):
    id: int
    name: str
    is_admin: bool
    created_at: datetime


class TokenCreate(BaseModel):
    """Options of a new token (the body may be omitted)."""

    model_config = ConfigDict(extra="forbid")

    label: Label = "api"
    ttl_s: int | None = Field(default=None, ge=60, description="lifetime [s], at most the remaining lifetime of the minting token "
                                  "(422 beyond); default: the server's token_ttl_s, ending no later than the minting token")


class TokenOut(BaseModel):
    """A token just minted: the secret is in this answer only (the server keeps its hash)."""

    user_id: int
    token: str
    expires_at: datetime | None = None
    id: int | None = Field(default=None, description="the token's id (GET /v1/tokens, DELETE /v1/tokens/{id})")
    label: str | None = None


class TokenInfoOut(_Out):
    """One of the caller's tokens as ``GET /v1/tokens`` lists it: never the token itself nor its hash.

    When a token was last used is not recorded (that would be a database write on every request, the batch
    uploads included).
    """

    id: int
    label: str
    created_at: datetime
    expires_at: datetime | None = Field(description="null: never expires")
    revoked: bool
    live: bool = Field(description="usable: neither revoked nor expired")
    current: bool = Field(description="the token of this request")


class DeviceCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    kind: DeviceKind
    name: Label = ""


class DeviceOut(_Out):
    id: int
    kind: str
    name: str
    created_at: datetime


_COORD = {"strict": True, "allow_inf_nan": False}
"""A coordinate is a JSON number: a string ("12.5") or a boolean was converted and taken (strict), NaN and
infinities are refused too."""


class SessionCreate(BaseModel):
    """Start of a session. The anchor (the WGS-84 position of the first stance) is optional: without it
    GeoJSON/GPX/KML exports are refused (409) and north stays the engine's; it can be set later (PATCH).

    ``placement`` decides the pipeline (DESIGN.md "Placement"): ``foot`` runs the ZUPT-KF / Gait-DR engine, the
    others the step-and-heading engine. Omitted: a foot sensor is on the foot, a watch on the wrist, and a phone's
    placement (hand or pocket) is recognised by the engine, a change reported as a ``placement_changed`` event. A
    placement the device kind cannot have (a watch in a pocket) is 422.

    Unknown fields are refused: ``latitude`` for ``latitude_deg`` started a session without a geodetic start.
    Coordinates are JSON numbers (integers too) within range: latitude -90..90 deg, longitude -180..180 deg,
    altitude -500..10 000 m, and ``device_id`` a JSON integer; anything else is 422 naming the field.
    """

    model_config = ConfigDict(extra="forbid")

    device_kind: DeviceKind
    placement: Placement | None = None
    device_id: int | None = Field(default=None, strict=True, **_ID)  # "5" or true: 422; the id column's range
    latitude_deg: float | None = Field(default=None, ge=-90.0, le=90.0, **_COORD)
    longitude_deg: float | None = Field(default=None, ge=-180.0, le=180.0, **_COORD)
    altitude_m: float | None = Field(default=None, ge=-500.0, le=10_000.0, **_COORD)
    anchor_date: date | None = Field(default=None, description="date of the World Magnetic Model's declination "
                                     "(default: the session's creation date, UTC)")
    anchor_accuracy_m: float | None = Field(default=None, ge=0.0, le=1e7, description="horizontal accuracy of the "
                                            "anchor [m] (a location fix's)", **_COORD)


class SessionPatch(BaseModel):
    """Changes to a session: its anchor. Fields left out stay; ``latitude_deg`` and ``longitude_deg`` null
    (together) remove the anchor. The stored positions are not touched: a trajectory is geo-referenced when read
    (``models.geo.georeference``), so a new anchor moves every export at once."""

    model_config = ConfigDict(extra="forbid")

    latitude_deg: float | None = Field(default=None, ge=-90.0, le=90.0, **_COORD)
    longitude_deg: float | None = Field(default=None, ge=-180.0, le=180.0, **_COORD)
    altitude_m: float | None = Field(default=None, ge=-500.0, le=10_000.0, **_COORD)
    anchor_date: date | None = None
    anchor_accuracy_m: float | None = Field(default=None, ge=0.0, le=1e7, **_COORD)


class DistanceIn(BaseModel):
    """A distance walked between two times of the session (user-entered, or measured by a foot sensor or GNSS)."""

    model_config = ConfigDict(extra="forbid")

    t0_ns: int = Field(strict=True, ge=-(2**63), le=2**63 - 1, description="start of the stretch [ns], device clock")
    t1_ns: int = Field(strict=True, ge=-(2**63), le=2**63 - 1, description="its end [ns], after t0_ns")
    distance_m: float = Field(gt=0.0, le=100_000.0, strict=True, allow_inf_nan=False, description="distance walked [m]")


class SensorConfigOut(BaseModel):
    gyro_on: bool
    acc_rate_hz: float
    gyr_rate_hz: float
    mag_rate_hz: float
    batch_s: float = 1.0  # seconds of data per upload (rows stored before the engine had it: 1 s)
    # gyroscope off, but the device turns it on by itself when its accelerometer departs from the still reference
    # by more than wake_threshold_ms2 [m/s^2] on an axis, and off after sleep_after_s [s] of stillness
    # (energy.types.SensorConfig; rows stored before these fields existed: no wake-on-motion)
    gyro_wake_on_motion: bool = False
    wake_threshold_ms2: float = 0.0
    sleep_after_s: float = 0.0
    # with gyro_wake_on_motion: the magnetometer sleeps and wakes with the gyroscope (rows stored before: False)
    mag_follows_gyro: bool = False
    # with gyro_wake_on_motion: "motion" (departure from the still reference), "high_g" (absolute specific force
    # on an axis beyond the threshold: a run while Gait-DR has only a walking model; rows stored before: "motion")
    # or "weak_field" (a still stance whose calibrated field, W (m - mag_offset_ut) with W = mag_matrix row-major,
    # has a horizontal part below wake_field_ut [uT]: the compass cannot tell turns there) or "compass_swing" (a
    # phone's tilt-compensated compass azimuth changes by more than wake_swing_rad [rad] within wake_window_s [s]:
    # a turn made with the gyroscope off; rows stored before these fields existed: 0, 0)
    wake_mode: Literal["motion", "high_g", "weak_field", "compass_swing"] = "motion"
    wake_field_ut: float = 0.0
    mag_offset_ut: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_matrix: tuple[float, float, float, float, float, float, float, float, float] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    wake_swing_rad: float = 0.0
    wake_window_s: float = 0.0
    # with gyro_on: a duty-cycled gyroscope, powered up by the device every gyr_duty_period_s [s] of its own clock and
    # delivering gyr_duty_on_s [s] after its turn-on time (energy.types.SensorConfig; rows stored before these
    # fields existed: 0, 0 = not duty-cycled)
    gyr_duty_period_s: float = 0.0
    gyr_duty_on_s: float = 0.0


class SessionOut(_Out):
    id: int
    device_kind: str
    placement: str | None = Field(default=None, description="placement given at the start; null: recognised by the engine")
    device_id: int | None
    latitude_deg: float | None
    longitude_deg: float | None
    altitude_m: float | None
    status: str
    created_at: datetime
    closed_at: datetime | None
    next_seq: int
    behaviour: str
    mode: str
    sensor_config: SensorConfigOut | None
    n_positions: int
    reprocessed_at: datetime | None = None
    reprocess_count: int = 0
    anchor_date: date | None = None
    anchor_accuracy_m: float | None = None
    anchor_source: str | None = None

    @computed_field(description="World Magnetic Model declination at the anchor and its date [deg] (positive east; "
                    "null without an anchor); applied to the trajectory when the engine's north is magnetic")
    def declination_deg(self) -> float | None:
        from models.geo import magnetic_elements

        anchor = session_anchor(self)
        return None if anchor is None else math.degrees(magnetic_elements(anchor).declination_rad)


def session_anchor(sess: Any) -> Any:
    """The :class:`models.geo.Anchor` of a session row (or :class:`SessionOut`), None without one."""
    from models.geo import Anchor

    if sess.latitude_deg is None or sess.longitude_deg is None:
        return None
    d = sess.anchor_date or (sess.created_at.date() if sess.created_at is not None else None)
    kw: dict[str, Any] = {"accuracy_m": sess.anchor_accuracy_m, "source": sess.anchor_source or "user"}
    if d is not None:
        kw["date"] = d
    return Anchor(float(sess.latitude_deg), float(sess.longitude_deg), float(sess.altitude_m or 0.0), **kw)


class PositionOut(BaseModel):
    t_ns: int
    north: float
    east: float
    down: float
    heading_rad: float
    behaviour: str
    mode: str
    step_length_m: float
    gyro_on: bool


class EventOut(BaseModel):
    t_ns: int
    kind: str
    detail: dict[str, Any]


class BatchResponse(BaseModel):
    """Answer to an accepted batch; a retried batch gets exactly the same answer."""

    session_id: int
    seq: int
    next_seq: int
    positions: list[PositionOut]
    events: list[EventOut]
    behaviour: str
    mode: str
    sensor_config: SensorConfigOut


class ProfileIn(BaseModel):
    model_config = ConfigDict(extra="forbid")

    data: dict[str, Any]


class ProfileOut(BaseModel):
    behaviour: str
    version: int
    data: dict[str, Any] | None
    source: str
    created_at: datetime


class GaitSummaryOut(BaseModel):
    """Per session gait figures of one user, oldest first (heading deviation: 004 Section 4.2).

    Each session: ``session_id``, ``started``, ``device_kind``, ``steps``, ``distance_m``,
    ``mean_step_length_m``, ``cadence_steps_per_min``, ``heading_deviation_rad`` / ``heading_deviation_var``
    (latest estimate, null when none) and ``heading_deviation`` (its estimates over time).
    """

    sessions: list[dict[str, Any]]
    heading_deviation_over_time: list[dict[str, Any]] = Field(
        default_factory=list, description="every estimate of the user, oldest session first: session_id, t_ns, "
        "event, behaviour, heading_deviation_rad, heading_deviation_var")


_INT64 = {"ge": -(2**63), "le": 2**63 - 1}  # stored as BIGINT: a larger number made the driver fail (HTTP 500)


class SensorLoggerItem(BaseModel):
    name: str
    # strict: a string "1700000000000000000", a float 1.7e18 or true was read as a time [ns]; the values
    # x, y, z are checked as numbers (not strings, not booleans) by the route
    time: int = Field(strict=True, **_INT64)
    values: dict[str, Any]


class SensorLoggerPush(BaseModel):
    messageId: int = Field(**_INT64)  # noqa: N815 - Sensor Logger's own field names
    # columns of 100 characters (PostgreSQL refused longer: 500), no control characters (NUL: 500)
    sessionId: Annotated[Label, Field(min_length=1)]  # noqa: N815 - Sensor Logger's own field names
    deviceId: Label = ""  # noqa: N815
    payload: list[SensorLoggerItem]


class ReprocessIn(BaseModel):
    """Options of a re-processing run (the body may be omitted)."""

    model_config = ConfigDict(extra="forbid")

    engine_mode: Literal["auto", "zupt", "pdr"] | None = Field(
        default=None, description="engine mode of the re-run; default: the session's own")
    dry_run: bool = Field(default=False, description="compute and compare only; store nothing")


class ReprocessOut(BaseModel):
    """Result of re-processing a session from its stored raw batches."""

    session_id: int
    engine: str = Field(description="engine class that produced the new trajectory")
    engine_mode: str
    batches: int = Field(description="stored batches fed, in sequence order")
    positions_before: int
    positions_after: int
    events_after: int
    identical: bool = Field(description="every stored position field equals the previous trajectory's")
    max_shift_m: float | None = Field(description="largest 3-D displacement [m] when the positions have the same times")
    stored: bool = Field(description="false for a dry run")
    reprocess_count: int

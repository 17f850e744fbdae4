"""Device simulators: a foot sensor, a phone and a watch streaming a recording through the SDK.

The phone and the watch stream phone- and watch-like signals: by default a synthetic walk carried in the hand /
on the wrist (:mod:`clients.phone_synth`), and they start their sessions with their placement (the phone's left to
the server to recognise unless given), so the server runs the step-and-heading engine for them; the foot sensor
streams whatever foot recording it is given.

Each simulator behaves like the real device talking to the server: it sends ``batch_seconds`` of samples
per request and, after every answer, applies the server's sensor configuration from the next batch on —
gyroscope off means no gyroscope samples are sent (with wake-on-motion, until the device's accelerometer sees
motion); a lower rate is produced by the anti-aliased decimation of
:class:`energy.device.DeviceEmulator` (the same de-sampling the local replay uses, so streamed and local
processing see identical samples).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from clients.recording import Recording
from clients.sdk import AsyncPednavClient, PednavClient
from energy.device import DeviceEmulator
from energy.types import SensorConfig
from models.batch import STREAMS, SensorBatch

__all__ = [
    "SimulationResult",
    "DeviceSimulator",
    "FootSensorSimulator",
    "PhoneSimulator",
    "WatchSimulator",
    "simulator_for",
]


@dataclass
class SimulationResult:
    """What a simulated device sent and got back.

    Attributes
    ----------
    session_id : int
    responses : list of dict
        Server answers, one per batch (the close adds the flushed positions to ``positions``).
    positions : list of dict
        Every position received, in order (``t_ns``, ``north``/``east``/``down`` [m], ``mode`` ...).
    samples_sent : dict of str to int
        Samples sent per stream.
    bytes_sent : int
        Request body bytes of all uploads.
    gyro_on_s : float
        Time during which the gyroscope was on [s] (powered, as the device reports it: with
        ``SensorConfig.gyro_wake_on_motion`` the device turns it on by itself on motion).
    duration_s : float
        Recording duration [s].
    configs : list of (int, dict)
        Batch start time [ns] and the sensor configuration used for it.
    spans : list of list of tuple
        Per batch (parallel to ``configs``), the device's stretches of constant sensor state
        ``(t0_ns, t1_ns, acc_hz, gyr_hz, mag_hz)`` (:attr:`energy.device.DeviceEmulator.last_spans`; a
        wake-on-motion gyroscope runs for part of a batch).
    """

    session_id: int
    responses: list[dict[str, Any]] = field(default_factory=list)
    positions: list[dict[str, Any]] = field(default_factory=list)
    samples_sent: dict[str, int] = field(default_factory=lambda: {s: 0 for s in STREAMS})
    bytes_sent: int = 0
    gyro_on_s: float = 0.0
    duration_s: float = 0.0
    configs: list[tuple[int, dict[str, Any]]] = field(default_factory=list)
    spans: list[list[tuple[int, int, float, float, float]]] = field(default_factory=list)

    @property
    def gyro_on_fraction(self) -> float:
        return self.gyro_on_s / self.duration_s if self.duration_s > 0 else 0.0


class DeviceSimulator:
    """A device obeying the server's sensor configuration.

    Parameters
    ----------
    recording : Recording or SensorBatch
        Native-rate streams (SI units, int64 ns timestamps).
    batch_seconds : float or None
        Duration of each uploaded batch [s]; None: as long as the server's sensor configuration says
        (``SensorConfig.batch_s``: longer uploads while the gyroscope is off).
    """

    kind = "foot"
    placement: str | None = "foot"

    def __init__(self, recording: Recording | SensorBatch, batch_seconds: float | None = 1.0) -> None:
        self.recording = recording if isinstance(recording, Recording) else None
        self.batch = recording.batch if isinstance(recording, Recording) else recording
        if self.batch.t_start_ns is None:
            raise ValueError("recording: no samples")
        if batch_seconds is not None and batch_seconds <= 0:
            raise ValueError("batch_seconds must be positive")
        self.batch_seconds = batch_seconds

    def _windows(self, config: Callable[[], SensorConfig]) -> Iterator[tuple[int, int]]:
        """Upload windows ``[t0, t1)`` [ns]; ``config`` is read before each (it may change the length)."""
        t0, t_end = self.batch.t_start_ns, self.batch.t_end_ns
        assert t0 is not None and t_end is not None
        while t0 <= t_end:
            seconds = self.batch_seconds if self.batch_seconds is not None else config().batch_s
            t1 = min(t0 + max(int(round(seconds * 1e9)), 1), t_end + 1)
            yield t0, t1
            t0 = t1

    def _start_kwargs(self, start: dict[str, Any] | None) -> dict[str, Any]:
        base: dict[str, Any] = {"device_kind": self.kind}
        if self.placement is not None:
            base["placement"] = self.placement
        return {**base, **(start or {})}

    def run(
        self,
        client: PednavClient,
        session: dict[str, Any] | None = None,
        start: dict[str, Any] | None = None,
        close: bool = True,
        progress: Callable[[float, list[dict[str, Any]]], None] | None = None,
    ) -> SimulationResult:
        """Stream the whole recording; returns what was sent and received.

        Parameters
        ----------
        client : PednavClient
        session : dict, optional
            An existing session document; a new session is started otherwise (``start`` = its extra fields,
            e.g. ``latitude_deg``).
        close : bool
            Close the session at the end (the server flushes the engine's last positions).
        progress : callable, optional
            ``progress(fraction_done, new_positions)`` after every batch.
        """
        sess = session or client.start_session(**self._start_kwargs(start))
        res = SimulationResult(session_id=sess["id"])
        stream = client.stream(sess["id"], sess.get("next_seq", 0))
        config = SensorConfig(**sess["sensor_config"])
        device = DeviceEmulator(self.batch)
        start_ns, span = int(self.batch.t_start_ns or 0), int(self.batch.t_end_ns or 0) + 1 - int(self.batch.t_start_ns or 0)
        res.duration_s = span / 1e9
        for t0, t1 in self._windows(lambda: config):
            res.configs.append((t0, config.to_dict()))
            out = device.emit(t0, t1, config)
            res.spans.append(list(device.last_spans))
            # powered time, a wake-on-motion gyroscope's included (it may start or stop within the batch)
            res.gyro_on_s += sum(b - a for a, b, _, gyr, _ in device.last_spans if gyr > 0) / 1e9
            for name in STREAMS:
                res.samples_sent[name] += len(out.stream(name)[0])
            answers = stream.send(out)
            new: list[dict[str, Any]] = []
            for a in answers:
                res.responses.append(a)
                new += a["positions"]
            res.positions += new
            if stream.sensor_config is not None:
                config = SensorConfig(**stream.sensor_config)
            if progress is not None:
                progress((t1 - start_ns) / span, new)
        res.bytes_sent = stream.bytes_sent
        if stream.pending:
            raise ConnectionError(f"{len(stream.pending)} batches could not be delivered")
        if close:
            before = len(client.trajectory(sess["id"])["positions"])
            client.close_session(sess["id"])
            res.positions += client.trajectory(sess["id"])["positions"][before:]
        return res

    async def run_async(
        self,
        client: AsyncPednavClient,
        session: dict[str, Any] | None = None,
        start: dict[str, Any] | None = None,
        close: bool = True,
    ) -> SimulationResult:
        """Asynchronous :meth:`run` (many simulated devices in one event loop: the load benchmark)."""
        sess = session or await client.start_session(**self._start_kwargs(start))
        res = SimulationResult(session_id=sess["id"])
        stream = client.stream(sess["id"], sess.get("next_seq", 0))
        config = SensorConfig(**sess["sensor_config"])
        device = DeviceEmulator(self.batch)
        res.duration_s = (int(self.batch.t_end_ns or 0) + 1 - int(self.batch.t_start_ns or 0)) / 1e9
        for t0, t1 in self._windows(lambda: config):
            out = device.emit(t0, t1, config)
            for a in await stream.send(out):
                res.responses.append(a)
                res.positions += a["positions"]
            if stream.sensor_config is not None:
                config = SensorConfig(**stream.sensor_config)
        if close:
            await client.close_session(sess["id"])
        return res


class FootSensorSimulator(DeviceSimulator):
    """A foot-mounted IMU paired with a phone (the phone relays its batches)."""

    kind = "foot"
    placement = "foot"


class PhoneSimulator(DeviceSimulator):
    """A phone's own IMU (Android ``SensorEvent`` streams).

    Parameters
    ----------
    recording : Recording or SensorBatch, optional
        What the phone measured; default: the synthetic ``phone-walk`` (held in the hand,
        :func:`clients.phone_synth.synthesize_phone`).
    batch_seconds : float or None
    placement : {"phone-hand", "phone-pocket", "foot"} or None
        Told to the server at the session start; None: the server's engine recognises it.
    """

    kind = "phone"

    def __init__(self, recording: Recording | SensorBatch | None = None, batch_seconds: float | None = 1.0,
                 placement: str | None = None) -> None:
        if recording is None:
            from clients.phone_synth import synthesize_phone

            recording = synthesize_phone("phone-walk")
        super().__init__(recording, batch_seconds)
        self.placement = placement


class WatchSimulator(DeviceSimulator):
    """A smartwatch IMU on the wrist (default recording: the synthetic ``watch-walk``)."""

    kind = "watch"
    placement = "watch"

    def __init__(self, recording: Recording | SensorBatch | None = None, batch_seconds: float | None = 1.0) -> None:
        if recording is None:
            from clients.phone_synth import synthesize_phone

            recording = synthesize_phone("watch-walk")
        super().__init__(recording, batch_seconds)


def simulator_for(kind: str, recording: Recording | SensorBatch | None, batch_seconds: float | None = 1.0,
                  placement: str | None = None) -> DeviceSimulator:
    """The simulator for a device kind (``foot``, ``phone``, ``watch``); ``placement`` as the client states it
    (default: the kind's own; a phone's None = recognised by the server)."""
    if kind == "foot":
        if recording is None:
            raise ValueError("recording: a foot sensor simulator needs a foot recording")
        sim: DeviceSimulator = FootSensorSimulator(recording, batch_seconds)
    elif kind == "phone":
        sim = PhoneSimulator(recording, batch_seconds, placement)
    elif kind == "watch":
        sim = WatchSimulator(recording, batch_seconds)
    else:
        raise ValueError(f"kind: expected one of ['foot', 'phone', 'watch'], got {kind!r}")
    if placement is not None and kind != "phone":
        sim.placement = placement
    return sim

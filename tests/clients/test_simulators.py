"""Device simulators obey the server's sensor configuration: gyroscope off -> no gyroscope samples sent,
rate changes -> the sent rate follows. The phone and the watch send phone- and watch-like signals and get the
step-and-heading engine."""

from __future__ import annotations

import pytest

from clients.sdk import PednavClient
from clients.simulators import FootSensorSimulator, PhoneSimulator, WatchSimulator, simulator_for
from energy.config import RatesConfig
from tests.server.conftest import app, backend, client, make_user, settings  # noqa: F401 - fixtures


@pytest.fixture(scope="module")
def walk_recording():  # type: ignore[no-untyped-def]
    from clients.synth import synthesize

    return synthesize("walk", seed=7)


@pytest.mark.parametrize("cls", [FootSensorSimulator, PhoneSimulator, WatchSimulator])
def test_simulator_obeys_sensor_configuration(client, make_user, walk_recording, cls) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    _, tok = make_user()
    api = PednavClient(token=tok, http=client)
    foot = cls is FootSensorSimulator
    sim = cls(walk_recording, batch_seconds=1.0) if foot else cls(batch_seconds=1.0)  # phone/watch: their own signals
    walk_recording = sim.recording
    res = sim.run(api)
    sess = api.session(res.session_id)
    assert sess["device_kind"] == cls.kind
    assert sess["placement"] == {"foot": "foot", "phone": None, "watch": "watch"}[cls.kind]
    stored = api._json("GET", f"/v1/sessions/{res.session_id}/batches")
    assert len(stored) == len(res.configs)
    gyro_states = {c["gyro_on"] for _, c in res.configs}
    rates = {c["acc_rate_hz"] for _, c in res.configs}
    # the scenario makes the scheduler switch: otherwise this test would prove nothing. The step-and-heading
    # engine keeps one accelerometer rate in auto and switches the gyroscope off standing once its bias has
    # settled: the watch's walk begins with a 20-s rest that settles it; the phone's stands (3-6 s) do not, so
    # its gyroscope stays on (what its batches must then carry is checked below all the same)
    assert gyro_states == ({True} if cls is PhoneSimulator else {True, False}) and (len(rates) > 1 or not foot)
    # the foot engine's answers carry wake-on-motion (the new user's first stand once levelled), and the device
    # obeys it; the step-and-heading engine switches the gyroscope itself, step by step
    assert any(c.get("gyro_wake_on_motion") for _, c in res.configs) == foot
    if not foot:
        assert all(p["mode"] == "pdr" for p in res.positions) and len(res.positions) > 40
    assert len(res.spans) == len(res.configs)
    native = walk_recording.batch.rate_hz("acc")
    steady = 0
    for k, ((t0, cfg), b) in enumerate(zip(res.configs, stored)):
        wake = cfg.get("gyro_wake_on_motion", False)  # the device may turn the gyroscope on by itself
        if cfg["gyro_on"]:
            assert b["n_gyr"] > 0
        elif not wake:
            assert b["n_gyr"] == 0
        # full 1-s batches under an unchanged command: the accelerometer count follows the commanded rate
        # (native / integer factor); batches right after a change lose the anti-aliasing filter's delay
        factor = max(1, round(native / cfg["acc_rate_hz"]))
        # (two batches: the 5-Hz magnetometer's anti-aliasing filter delays its output by 1.6 s)
        if 1 < k < len(stored) - 1 and res.configs[k - 1][1] == cfg == res.configs[k - 2][1] and not (wake and b["n_gyr"] > 0):
            steady += 1
            assert abs(b["n_acc"] - native / factor) <= 1, (cfg, b)
            if cfg["mag_rate_hz"] > 0 and not (cfg.get("mag_follows_gyro") and b["n_gyr"] == 0):
                mag = walk_recording.batch.rate_hz("mag")
                assert abs(b["n_mag"] - mag / max(1, round(mag / cfg["mag_rate_hz"]))) <= 1, (cfg, b)
            else:  # no magnetometer commanded, or one that runs only with a woken gyroscope that stayed asleep
                assert b["n_mag"] == 0
    assert steady > len(stored) / 2
    assert sum(b["n_acc"] for b in stored) == res.samples_sent["acc"]
    assert 0.0 < res.gyro_on_fraction <= (1.0 if cls is PhoneSimulator else 0.999)


def test_simulator_for_kinds(walk_recording) -> None:  # type: ignore[no-untyped-def]
    assert isinstance(simulator_for("watch", walk_recording), WatchSimulator)
    with pytest.raises(ValueError):
        simulator_for("toaster", walk_recording)
    with pytest.raises(ValueError):
        FootSensorSimulator(walk_recording, batch_seconds=0)
    with pytest.raises(ValueError, match="foot recording"):
        simulator_for("foot", None)


@pytest.mark.parametrize("cls, placement", [(PhoneSimulator, "phone-hand"), (WatchSimulator, "watch")])
def test_phone_and_watch_send_their_own_kind_of_signal(cls, placement) -> None:  # type: ignore[no-untyped-def]
    """Not a foot's: the phone's tilt stays steady and its field never swings through a stride; the wrist swings."""
    import numpy as np

    sim = cls()
    assert sim.recording.truth.extra["placement"] == placement
    b = sim.batch
    gyr = np.linalg.norm(b.gyr, axis=1)
    # a foot's gyroscope peaks at several rad/s every stride and its accelerometer at several g
    assert np.percentile(np.linalg.norm(b.acc, axis=1), 99) < 30.0
    assert (np.median(gyr) < 0.5) == (placement == "phone-hand")


def test_simulator_uploads_as_long_as_the_server_says(client, make_user, walk_recording) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    _, tok = make_user()
    api = PednavClient(token=tok, http=client)
    res = FootSensorSimulator(walk_recording, batch_seconds=None).run(api)
    spans = [(b - a) / 1e9 for (a, _), (b, _) in zip(res.configs, res.configs[1:])]
    wanted = [c["batch_s"] for _, c in res.configs[:-1]]
    assert spans == pytest.approx(wanted, abs=1e-9)
    assert {RatesConfig().batch_s, RatesConfig().low_power_batch_s} <= set(wanted)  # the scheduler asked for both, so this proves something
    stored = api._json("GET", f"/v1/sessions/{res.session_id}/batches")
    assert len(stored) == len(res.configs) and sum(b["n_acc"] for b in stored) == res.samples_sent["acc"]

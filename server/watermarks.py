"""Per-session stream watermarks: the newest gyroscope and magnetometer sample time a session received.

The engine refuses accelerometer samples older than those it processed (422) but drops gyroscope and
magnetometer samples that are not after the newest one it holds, without a word: a batch that carried the
previous batch's gyroscope samples again was answered 200 and moved the end point 0.29 m after 30 s. The
server keeps the newest time of each of these streams in the session row (``gyr_newest_ns``,
``mag_newest_ns``, read with the session on every upload) and refuses such a batch with a 422 that names the
stream, before the engine sees it: nothing is stored and the sequence number stays free.
"""

from __future__ import annotations

from models.batch import BatchError, SensorBatch

__all__ = ["WATERMARKED", "check_after", "advanced"]

WATERMARKED = ("gyr", "mag")
"""The streams whose late samples the engine would drop silently (the accelerometer's it refuses itself)."""

_NAMES = {"gyr": "gyroscope", "mag": "magnetometer"}


def check_after(batch: SensorBatch, newest: dict[str, int | None]) -> None:
    """Raise :class:`BatchError` naming ``<stream>_t_ns`` when the first sample of a watermarked stream of
    ``batch`` is not after ``newest[stream]`` [ns] (None: the session has none yet)."""
    for name in WATERMARKED:
        t, _ = batch.stream(name)
        last = newest.get(name)
        if len(t) and last is not None and int(t[0]) <= last:
            n_late = int((t <= last).sum())
            raise BatchError(
                f"{name}_t_ns",
                f"{n_late} {_NAMES[name]} sample(s) at or before {last} ns, the newest this session already received "
                f"(first at {int(t[0])} ns); the engine cannot use samples older than those it processed: send each "
                "sample once, in time order")


def advanced(batch: SensorBatch, newest: dict[str, int | None]) -> dict[str, int | None]:
    """The watermarks after ``batch`` was taken (each the later of the old one and the stream's last sample)."""
    out = dict(newest)
    for name in WATERMARKED:
        t, _ = batch.stream(name)
        if len(t):
            last = int(t[-1])
            out[name] = last if out.get(name) is None else max(int(out[name]), last)  # type: ignore[arg-type]
    return out

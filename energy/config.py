"""Engine settings: one configuration serves every user and recording."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

__all__ = ["EngineConfig"]


@dataclass(frozen=True)
class EngineConfig:
    """Settings of the engine; one configuration serves every user and recording.

    Parameters
    ----------
    full_rate_hz : float
        Accelerometer/gyroscope rate requested while the ZUPT-KF runs [Hz].
    pdr_rate_hz : float
        Accelerometer/magnetometer rate requested in Gait-DR (004 Section 4.3) [Hz].
    stand_rate_hz : float
        Accelerometer rate while standing with the gyroscope off [Hz]: the lowest rate at which the step
        segmentation still counts the steps taken before the device hears that the person walks again.
    mag_rate_hz : float
        Magnetometer rate while the ZUPT-KF runs [Hz].
    l0_m : float
        Distance walked under the ZUPT-KF before switching to Gait-DR (004 Table 2, L0) [m].
    t0_s : float
        Interval between step-length model examinations in Gait-DR (004 Table 1/3, T0) [s].
    max_sample_age_s : float
        A gyroscope/magnetometer sample older than this is not paired with an accelerometer sample [s].
    exam_timeout_s : float
        An examination with no ZUPT-KF stride after this long is given up [s].
    heading_assist : bool
        In Gait-DR, turn the gyroscope on while the magnetic field is disturbed (auto mode) instead of
        holding the last good compass heading. Off: on gdin it cost gyroscope time and made positions worse
        (the ZUPT-KF restarts from the held heading, so a turn missed before the gyroscope woke stays missed,
        and the compass no longer re-anchors the heading while the gyroscope runs).
    weak_field_h : float
        In Gait-DR (auto mode), turn the gyroscope on while the stance field's horizontal part is below this
        fraction of the Earth's (the compass's reference m_n): a few uT of disturbance per stride turn such a
        field by tens of degrees, so the compass can no longer tell a turn of the foot from one of the field
        (synthetic mixed days, seeds 13 and 19: steel left 1.5-4 uT of a 22-uT horizontal field, the compass
        swung by 30-50 deg a stride and Gait-DR ran 50-140 deg off). 0: never.
    weak_field_wake : bool
        With ``weak_field_h``: in Gait-DR the device wakes the gyroscope itself at the first still stance whose
        field is that weak (``SensorConfig.wake_mode`` ``"weak_field"``, with the compass's calibration), instead
        of the host asking for it after its next upload, up to 4 s and several strides later (held-out random
        day, seed 2, returning user: a 68-deg turn in that gap was lost, 15.3 m of mean error; with it 2.1 m).
    pdr_conventional : bool
        Evaluation baseline: Gait-DR as "conventional PDR" (004 Table 6: generic step model, no heading-deviation
        compensation), see :class:`energy.gait_dr.GaitPipeline`. Off in the product.
    """

    full_rate_hz: float = 200.0
    pdr_rate_hz: float = 25.0
    stand_rate_hz: float = 25.0
    mag_rate_hz: float = 50.0
    l0_m: float = 40.0
    t0_s: float = 30.0
    max_sample_age_s: float = 0.05
    exam_timeout_s: float = 10.0
    heading_assist: bool = False
    weak_field_h: float = 0.3
    weak_field_wake: bool = True
    pdr_conventional: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}  # flat: no deep copy

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EngineConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"EngineConfig: unknown fields {sorted(unknown)}")
        return cls(**d)

"""Streaming ZUPT-aided MARG navigator (004 Sec. 2): detector + strapdown + 15-state error-state KF.

The per-sample work runs in one compiled kernel (:mod:`models._zupt_kernel`); this module holds the
streaming buffer (the detector looks ``half_window_s`` ahead, so the newest samples are held back until
their window is complete or :meth:`ZuptNavigator.flush` is called), input validation and the state
(de)serialisation. Feeding a recording in one piece or in arbitrary pieces gives identical outputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from models import _zupt_kernel as _k
from models.attitude import align_at_rest
from models.rotations import dcm_to_quat
from models.rows import RowBuffer
from models.saturation import SAT_ACC, SAT_GYR, ClipRepair, SaturationConfig

__all__ = ["ZuptConfig", "NavOutput", "Stance", "ZuptNavigator", "SAT_ACC", "SAT_GYR"]


@dataclass(frozen=True)
class ZuptConfig:
    """Every tunable of the navigator (one configuration serves all recordings; defaults = the project's).

    Detector (SHOE/GLRT, 002 eq. 1-3, with a gait-intensity adaptive threshold):
    ``sigma_a`` [m/s^2], ``sigma_w`` [rad/s], ``half_window_s`` [s] (centred window); threshold
    ``gamma = clip(gamma0 * (I / intensity_ref) ** gamma_exp, gamma_min, gamma_max)`` where the gait
    intensity ``I`` is, by ``intensity_mode``: 2 (default) the peak of the specific-force magnitude |a|
    [m/s^2] decaying with ``intensity_tau_s`` [s] (heel-strike intensity: running -> higher threshold, slow
    shuffling -> lower); 0 the decaying peak of the statistic itself; 1 an exponential mean of log10 of
    the statistic. A stance is left when the statistic exceeds ``hysteresis * gamma``; with
    ``erosion_s`` > 0 the statistic is the max over +-erosion_s (narrower stances).
    Filter (004 eq. 6-13): process PSDs ``acc_psd`` [(m/s^2)^2 s], ``gyr_psd`` [(rad/s)^2 s], bias random
    walks ``ba_psd``, ``bg_psd``; ZUPT noise ``zupt_sigma * (1 + zupt_soft * T / gamma)`` [m/s] (strong deep
    in the stance, weak at its edges where the foot may still move); gyro scale-factor uncertainty
    ``gyr_scale_sigma`` (relative: the attitude variance grows by (sigma * turned angle)^2); ZARU
    ``zaru_on``/``zaru_sigma`` [rad/s], applied only where the statistic is below ``zaru_gamma``; magnetic heading
    ``mag_on``/``mag_sigma`` [rad] gated by magnitude ``mag_dmag`` [uT], inclination ``mag_dinc`` [rad]
    and innovation ``mag_gate`` [sigma], once per stance from the stance's mean field.
    Heading aids (003 drift reduction): ``hdr_on`` pulls the heading back to the direction of the current
    straight segment (strides >= ``hdr_min_stride`` m within ``hdr_delta`` rad, after ``hdr_min_n``
    strides; noise ``hdr_sigma`` rad; a segment's direction is its first stride that agrees with the one that
    broke the previous segment, which may be the last of a turn; the foot turning beyond ``hdr_turn`` rad from
    the segment on two strides running by the gyroscope is a turn too, and takes back the pull of its first
    strides, 0 = off); ``dom_on`` snaps straight segments within ``dom_delta`` rad of the
    building's dominant directions (the first straight segment + k * 90 deg; indoor heuristic).
    Alignment (001 eq. 1-5 via TRIAD): the initial rest is where the statistic is below ``align_gamma``
    (after ``align_timeout_s`` [s] without such a rest, e.g. a noisy sensor, the adaptive detector's);
    at least ``align_min_s`` and at most ``align_max_s`` [s]; initial tilt/heading sigmas ``p0_tilt``,
    ``p0_yaw`` [rad], bias sigmas ``p0_ba`` [m/s^2], ``p0_bg`` [rad/s]; with ``bias_from_rest`` the gyro
    bias starts at the rest's mean rate times ``d / (d + bias_shrink_s)`` (d = rest duration [s]).
    Mid-walk start: a rate of at least ``align_swing_rate`` [rad/s] before that rest (a swinging foot; every
    dev recording's initial rest stays below 0.15 rad/s, a walking swing reaches 3-10 rad/s) means there is no
    rest to wait for: the first stance of the adaptive detector lasting ``align_stance_min_s`` [s] aligns roll
    and pitch (same equations on the quasi-still foot), heading from the field with ``mag_on``, else 0 (the
    heading of a frame without a compass is arbitrary); the gyro bias starts at 0 with sigma ``p0_bg_walk``
    [rad/s] (a stance's mean rate is the foot's roll-over, not the bias). The strides before it are lost.
    Fastest rotation: a sample whose largest single-axis |rate| is at least ``gyr_sat_min`` [rad/s] and within
    ``gyr_sat_frac`` of the largest seen so far grows the tilt variance by ``(gyr_sat_sigma * dt)^2`` [rad^2] (0 =
    off): the rate's error grows with it (latency, scale factor, bandwidth), and the next ZUPT re-levels.
    Range clipping (sensor saturation, :mod:`models.saturation`): a sample's axis sits at the sensor's full scale
    where ``|value|`` is within ``clip_flat`` of the range the device gives (``clip_acc_range`` [m/s^2],
    ``clip_gyr_range`` [rad/s]; 0 = not known) or, not known, where it is at least ``clip_acc_min`` [m/s^2] /
    ``clip_gyr_min`` [rad/s] (no part's range is smaller), within ``clip_frac`` of the largest |value| of that axis
    and sign so far, and a neighbouring sample holds the same value within ``clip_flat`` (a plateau at the extreme;
    VICON's gyroscope clips at 9.1-9.7 rad/s, gdin's at 8.7). A clipped run is repaired by the quadratic through
    ``clip_fit_n`` unclipped samples on either side (runs up to ``clip_max_s`` [s]; the samples are held back until
    it is decided), and each clipped value gets a 1-sigma error of ``clip_rel_sigma`` times what the repair added,
    at least ``clip_acc_sigma`` [m/s^2] / ``clip_gyr_sigma`` [rad/s]. That error persists over the run, so it
    becomes variance growing with the run's length along the clipped body axis in the navigation frame: velocity
    for the accelerometer; for the gyroscope tilt, which the next ZUPT re-levels (correcting velocity and position
    through the covariance), and heading, which no ZUPT observes: that part is kept out of the filter (in it, the
    ZUPTs turned the heading on velocity errors of other causes: gdin exp42 stride error 1.5 -> 2.4 m) and only
    reported, with the position error it causes over the distance travelled since (``NavOutput.heading_sigma``,
    ``pos_sigma``; each sample's clipped axes in ``NavOutput.saturated``).
    Inter-sensor latency: ``gyr_delay_s`` [s] >= 0 is how much the gyroscope's output lags the accelerometer's;
    the mechanisation then pairs each specific force with the rate read that much later (linear interpolation;
    the streaming look-ahead grows by it). Default 5 ms, measured without any truth: on level floors the foot
    ends every stride at the height it started, and the mean height change per stride (as a fraction of the
    stride length) crosses zero at a gyro lag of about 3.5 ms on the VICON trials and about 6 ms on the gdin
    walks (-0.5 % at 0 ms on both: the foot "climbs"); with 5 ms the strides are no longer systematically
    short (gdin median distance error 1.9 -> 0.7 %). A sensor without such a lag would then read strides
    about 1 % long: set 0 for it.
    Gaps in the data: an interval longer than ``gap_factor`` times the nominal one (the median of the latest
    9; 0 = off) up to ``gap_max_s`` [s] is integrated in steps of the nominal interval with rate and specific
    force linear between the samples on either side, and what that line misses (per axis ``gap_acc_sigma``
    [m/s^2], ``gap_gyr_sigma`` (tilt) and ``gap_yaw_sigma`` (heading) [rad/s], times the missed time) becomes
    covariance, so the next ZUPT takes the error out of velocity, position and tilt (defaults: the RMS error
    of linear interpolation over 0.05-0.3 s of real walking and running, 8.5 m/s^2 and 1-2.7 rad/s in 3-D).
    A longer gap may hold a whole stride: the position is held, the velocity dropped and the next stance
    re-levels roll and pitch (heading kept), so that stride is missing rather than long and wrong.
    Mid-swing pauses: no stance starts within ``swing_min_s`` [s] of the last one's end while the mechanised
    speed exceeds ``swing_speed`` [m/s]. So soon after a ZUPT the velocity errs by a few cm/s, so such a foot is
    moving whatever the statistic says. Stair ascent stops the foot's rotation 0.1-0.25 s into every swing at
    1.3-2 m/s; there the threshold, raised by the hard footfalls, took that for a stance and the ZUPT zeroed the
    climb (gaitmap stair-up: 1.4 m against the 4.5 m the same flight descends; 4.4 m with the rule). On the
    level it vetoes 1-4-sample "stances" (gdin: 0-7 per walk; VICON: 42 trials, mean ARMSE 2-D 0.081 -> 0.078 m).
    0.4 s rather than 0.3 s: on the real recordings (42 VICON trials, 26 gdin walks, gaitmap's two feet) the
    swings before a real stride (>= 0.3 m) last 0.435 s at the shortest where the foot moved faster than
    ``swing_speed`` (0.45 s at the 0.1th percentile, 2462 swings; one slow 0.23-s swing of gdin exp18 at 0.95 m/s
    is not vetoed), while the re-stances inside a stride that 0.3 s let through came 0.30-0.37 s after toe-off at
    1.3-3.4 m/s, 0.03-0.23 m from the last stance (gdin exp43: 3, exp42: 1; VICON 2018-02-22-10-10-29: 1;
    gaitmap right foot: 1). With 0.4 s: gdin exp43 63 -> 60 strides of 60, VICON mean ARMSE 2-D 0.0748 ->
    0.0745 m, gaitmap stride-length RMSE 0.079 -> 0.073 m, gdin mean stride error 0.618 -> 0.597 m.
    Other intervals longer than ``max_dt`` [s] (a very low rate) are integrated as ``max_dt``; stances shorter
    than ``min_stance_s`` [s] get ZUPTs but are not reported. ``first_order`` (comparison only) replaces the
    exponential-map attitude update by I + [w x] dt.

    Attributes
    ----------
    sigma_a : float
        Accelerometer noise of the stance statistic [m/s^2] (002 eq. 1).
    sigma_w : float
        Gyroscope noise of the stance statistic [rad/s] (002 eq. 1).
    half_window_s : float
        Half of the detector's centred window [s].
    gamma0 : float
        Stance threshold at the reference gait intensity [-] (002 eq. 3).
    gamma_exp : float
        Exponent of the threshold's adaptation to gait intensity [-] (0 = fixed threshold).
    intensity_tau_s : float
        Decay time of the gait-intensity peak tracker [s].
    intensity_ref : float
        Reference gait intensity [m/s^2] (mode 2: peak |a|; modes 0/1: units of the statistic).
    gamma_min : float
        Lowest adapted threshold [-].
    gamma_max : float
        Highest adapted threshold [-].
    hysteresis : float
        A stance ends when the statistic exceeds this times the threshold [-] (>= 1).
    gravity : float
        Local gravity magnitude [m/s^2].
    acc_psd : float
        Velocity random walk PSD [(m/s^2)^2 s] (004 eq. 6-8 process noise).
    gyr_psd : float
        Angle random walk PSD [(rad/s)^2 s].
    ba_psd : float
        Accelerometer bias random walk PSD [(m/s^2)^2/s].
    bg_psd : float
        Gyroscope bias random walk PSD [(rad/s)^2/s].
    zupt_sigma : float
        Zero-velocity pseudo-measurement noise deep in a stance [m/s] (004 eq. 9).
    zaru_sigma : float
        Zero-angular-rate pseudo-measurement noise [rad/s] (001 eq. 34-35).
    zaru_on : bool
        Apply ZARU on the still foot [-] (the only observation of the vertical gyro bias after the initial rest).
    mag_on : bool
        Apply the stance magnetic heading update [-] (004 eq. 10).
    mag_sigma : float
        Magnetic heading noise [rad].
    mag_dmag : float
        Field magnitude tolerance of the magnetic gate [uT] (002 eq. 4-5).
    mag_dinc : float
        Field inclination tolerance of the magnetic gate [rad].
    mag_gate : float
        Innovation gate of the magnetic update [sigma].
    align_min_s : float
        Shortest initial rest the alignment accepts [s].
    align_max_s : float
        Longest initial rest used by the alignment [s].
    max_dt : float
        Longest interval integrated in one step [s] (a longer one is integrated as this).
    p0_tilt : float
        Initial 1-sigma roll/pitch after alignment [rad].
    p0_yaw : float
        Initial 1-sigma heading [rad].
    p0_ba : float
        Initial 1-sigma accelerometer bias [m/s^2].
    p0_bg : float
        Initial 1-sigma gyroscope bias after a rest [rad/s] (the rest's estimate is trusted; re-estimating it by
        ZUPT hurt on real data).
    min_stance_s : float
        Shortest stance reported as a stance [s] (shorter ones still get ZUPTs).
    first_order : bool
        First-order attitude update I + [w x] dt instead of the exponential map [-] (comparison only).
    trapezoid : bool
        Integrate the mean of consecutive samples [-] (better at low rates).
    align_gamma : float
        Strict stance threshold that marks the initial rest for the alignment [-].
    align_timeout_s : float
        Without such a rest by then, align on the adaptive detector's first stance [s].
    zaru_gamma : float
        ZARU only where the statistic is below this [-] (a truly still foot).
    bias_from_rest : bool
        Start the gyro bias at the rest's mean rate, shrunk by d / (d + bias_shrink_s) [-].
    bias_shrink_s : float
        Prior weight of a zero gyro bias, as rest duration [s] (a short, restless rest says little).
    erosion_s : float
        The statistic is the max over +- this [s] (narrower stances; 0 = off).
    hdr_on : bool
        Heuristic drift reduction: straight strides keep their segment's heading [-] (003).
    hdr_sigma : float
        Noise of the drift-reduction pseudo-measurement [rad].
    hdr_delta : float
        A stride within this of the segment's heading counts as straight [rad].
    hdr_min_stride : float
        Shorter horizontal strides are ignored by the drift reduction [m].
    hdr_min_n : float
        Consistent strides needed before the drift reduction applies [strides].
    hdr_turn : float
        The foot turned this far from the segment on two strides running by the gyroscope: a turn [rad] (0 = off).
    dom_on : bool
        Snap straight segments to the building's dominant directions [-] (iHDE; indoor heuristic).
    dom_delta : float
        Snap only segments within this of a dominant direction [rad].
    gyr_scale_sigma : float
        Relative gyroscope scale-factor uncertainty [-] (attitude variance grows with the turned angle).
    zupt_soft : float
        ZUPT noise grows as zupt_sigma * (1 + zupt_soft * T / gamma) [-]: weak near the threshold.
    intensity_mode : int
        Gait intensity [-]: 0 decaying peak of the statistic, 1 exponential mean of its log10, 2 decaying peak
        of |a|.
    gyr_sat_frac : float
        A gyro axis within this fraction of the largest |rate| seen so far is the fastest rotation [-].
    gyr_sat_min : float
        ... but only above this rate [rad/s].
    gyr_sat_sigma : float
        1-sigma rate error of such a sample [rad/s] (tilt variance; 0 = off).
    clip_acc_range : float
        Accelerometer full scale from the device profile [m/s^2] (0 = not known: detected).
    clip_gyr_range : float
        Gyroscope full scale from the device profile [rad/s] (0 = not known: detected).
    clip_acc_min : float
        Smallest |specific force| taken for a detected clip [m/s^2] (no part's range is smaller).
    clip_gyr_min : float
        Smallest |rate| taken for a detected clip [rad/s].
    clip_frac : float
        A detected clip lies within this fraction of the axis's largest |value| of that sign so far [-].
    clip_flat : float
        Relative tolerance of the plateau at full scale [-].
    clip_fit_n : int
        Unclipped samples on either side of a clipped run fitted by the repair's quadratic [samples].
    clip_max_s : float
        Longest clipped run repaired [s] (the samples are held back until it is decided).
    clip_rel_sigma : float
        1-sigma error of a repaired value as a fraction of what the repair added [-].
    clip_acc_sigma : float
        Smallest 1-sigma error of a repaired specific force [m/s^2].
    clip_gyr_sigma : float
        Smallest 1-sigma error of a repaired rate [rad/s].
    gyr_delay_s : float
        How much the gyroscope's output lags the accelerometer's [s] (0 for a sensor without lag).
    align_swing_rate : float
        A rate this large before the initial rest means a mid-walk start [rad/s].
    align_stance_min_s : float
        Shortest walking stance a mid-walk start aligns on [s].
    p0_bg_walk : float
        Initial 1-sigma gyro bias of a mid-walk start [rad/s] (no rest to estimate it from).
    gap_factor : float
        An interval longer than this times the nominal one is a gap in the data [-] (0 = off).
    gap_acc_sigma : float
        Specific force per axis a linear interpolation over a gap misses [m/s^2].
    gap_gyr_sigma : float
        Tilt rate per axis a linear interpolation over a gap misses [rad/s].
    gap_yaw_sigma : float
        Heading rate a linear interpolation over a gap misses [rad/s] (no ZUPT observes it).
    gap_max_s : float
        A longer gap is not bridged: position held, re-levelled at the next stance [s].
    swing_min_s : float
        No stance starts this soon after the last one ended ... [s] (the shortest fast real swing before a stride
        lasts 0.435 s; the re-stances inside strides came 0.30-0.37 s after toe-off).
    swing_speed : float
        ... while the mechanised foot moves faster than this [m/s] (a mid-swing pause on stairs).
    """

    sigma_a: float = 0.01
    sigma_w: float = 0.1 * math.pi / 180.0
    half_window_s: float = 0.011
    gamma0: float = 1.2e5
    gamma_exp: float = 2.5
    intensity_tau_s: float = 1.5
    intensity_ref: float = 30.0
    gamma_min: float = 1.0e3
    gamma_max: float = 1.0e10
    hysteresis: float = 1.0
    gravity: float = 9.8
    acc_psd: float = 0.5**2 * 0.005
    gyr_psd: float = (0.5 * math.pi / 180.0) ** 2 * 0.005
    ba_psd: float = 1e-6
    bg_psd: float = 1e-12
    zupt_sigma: float = 0.01
    zaru_sigma: float = 0.5 * math.pi / 180.0
    # ZARU (001 eq. 24-35) on the foot at rest: the only observation of the vertical gyro bias left after the
    # initial rest's estimate (its shrink leaves 5 % of a 20-s rest's turn-on bias). Off, the always-on ZUPT-KF on
    # the held-out synthetic days drifted 2.2 % of the distance (mean error 7.6 m, typical part), on: 1.4 %
    # (5.3 m); gdin, VICON and gaitmap figures unchanged within 0.01 m / 0.02 % (their stands last 1-3 s).
    zaru_on: bool = True
    mag_on: bool = False
    mag_sigma: float = 10.0 * math.pi / 180.0
    mag_dmag: float = 3.0
    mag_dinc: float = 3.0 * math.pi / 180.0
    mag_gate: float = 3.0
    align_min_s: float = 0.1
    align_max_s: float = 3.0
    max_dt: float = 0.1
    p0_tilt: float = 1.0 * math.pi / 180.0
    p0_yaw: float = 1.0 * math.pi / 180.0
    p0_ba: float = 0.05
    p0_bg: float = 2e-4  # rad/s: trust the initial-rest gyro bias (re-estimating it via ZUPT hurt on real data)
    min_stance_s: float = 0.02
    first_order: bool = False
    trapezoid: bool = False
    align_gamma: float = 1.0e3
    align_timeout_s: float = 5.0
    zaru_gamma: float = 1.0e3
    bias_from_rest: bool = True
    bias_shrink_s: float = 1.0
    erosion_s: float = 0.0
    hdr_on: bool = True
    hdr_sigma: float = 0.02
    hdr_delta: float = 0.1
    hdr_min_stride: float = 0.3
    hdr_min_n: float = 2.0
    hdr_turn: float = 10.0 * math.pi / 180.0
    dom_on: bool = True
    dom_delta: float = 15.0 * math.pi / 180.0
    gyr_scale_sigma: float = 0.01
    zupt_soft: float = 10.0
    intensity_mode: int = 2
    gyr_sat_frac: float = 0.97
    gyr_sat_min: float = 4.0
    gyr_sat_sigma: float = 5.0
    clip_acc_range: float = 0.0
    clip_gyr_range: float = 0.0
    clip_acc_min: float = 19.0
    clip_gyr_min: float = 4.0
    clip_frac: float = 0.985
    clip_flat: float = 0.02
    clip_fit_n: int = 3
    clip_max_s: float = 0.06
    clip_rel_sigma: float = 0.5
    clip_acc_sigma: float = 1.0
    clip_gyr_sigma: float = 1.0
    gyr_delay_s: float = 0.005
    align_swing_rate: float = 2.0
    align_stance_min_s: float = 0.02
    p0_bg_walk: float = 2e-3
    gap_factor: float = 2.5
    gap_acc_sigma: float = 5.0
    gap_gyr_sigma: float = 1.0
    gap_yaw_sigma: float = 0.5
    gap_max_s: float = 0.35
    swing_min_s: float = 0.4
    swing_speed: float = 1.0

    def to_array(self) -> np.ndarray:
        """Parameter vector in the kernel's layout (:data:`models._zupt_kernel.PAR`)."""
        out = np.empty(_k.N_PAR)
        for name, idx in _k.PAR.items():
            out[idx] = float(getattr(self, name))
        return out

    def saturation(self) -> SaturationConfig:
        """The range-clipping settings as :class:`models.saturation.SaturationConfig`."""
        return SaturationConfig(
            acc_range=self.clip_acc_range, gyr_range=self.clip_gyr_range, acc_min=self.clip_acc_min,
            gyr_min=self.clip_gyr_min, frac=self.clip_frac, flat=self.clip_flat, fit_n=self.clip_fit_n,
            max_s=self.clip_max_s, rel_sigma=self.clip_rel_sigma, acc_sigma=self.clip_acc_sigma,
            gyr_sigma=self.clip_gyr_sigma)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first implausible setting."""
        for f in fields(self):
            v = getattr(self, f.name)
            if not math.isfinite(float(v)):
                raise ValueError(f"ZuptConfig.{f.name}: must be finite, got {v!r}")
        for name in ("sigma_a", "sigma_w", "half_window_s", "gamma0", "gravity", "zupt_sigma", "max_dt"):
            if getattr(self, name) <= 0:
                raise ValueError(f"ZuptConfig.{name}: must be > 0")
        if self.hysteresis < 1.0:
            raise ValueError("ZuptConfig.hysteresis: must be >= 1")
        if self.gyr_delay_s < 0 or self.gyr_delay_s > 0.1:
            raise ValueError("ZuptConfig.gyr_delay_s: must be within 0..0.1 s (the gyro lagging the accelerometer)")
        if not 0.0 < self.gyr_sat_frac <= 1.0:
            raise ValueError("ZuptConfig.gyr_sat_frac: must be in (0, 1]")
        self.saturation()  # raises ValueError naming the setting
        if self.gap_factor != 0.0 and self.gap_factor <= 1.0:
            raise ValueError("ZuptConfig.gap_factor: must be 0 (off) or > 1 (times the nominal sampling interval)")
        for name in ("align_swing_rate", "align_stance_min_s", "p0_bg_walk", "gap_acc_sigma", "gap_gyr_sigma",
                     "gap_yaw_sigma", "gap_max_s", "swing_min_s", "swing_speed", "hdr_turn"):
            if getattr(self, name) < 0:
                raise ValueError(f"ZuptConfig.{name}: must be >= 0")
        if self.gamma_min > self.gamma_max:
            raise ValueError("ZuptConfig.gamma_min: must not exceed gamma_max")


@dataclass(frozen=True)
class Stance:
    """One stance phase, reported once it ends.

    Attributes
    ----------
    t_start_s, t_end_s : float
        First stance sample and toe-off sample [s since session start].
    position : ndarray (3,)
        NED position at the end of the stance [m].
    heading : float
        Heading of the body x axis at heel strike [rad] (004 psi_i, eq. 19).
    delta : ndarray (3,)
        Position increment since the previous stance [m] (004 eq. 20; step-length calibration).
    peak_speed : float
        Largest speed in the swing before this stance [m/s].
    samples : int
        Stance samples. ``mag_used``: a magnetic heading update was applied at this stance.
    heading_sigma, pos_sigma : float
        1-sigma uncertainty of the heading [rad] and of the horizontal position [m] at the end of the stance
        (from the filter's covariance; NaN where not known).
    clipped : int
        Samples since the previous stance with an axis at the sensor's range (:class:`ZuptConfig`, range clipping).
    """

    t_start_s: float
    t_end_s: float
    position: np.ndarray
    heading: float
    delta: np.ndarray
    peak_speed: float
    samples: int
    mag_used: bool
    heading_sigma: float = math.nan
    pos_sigma: float = math.nan
    clipped: int = 0

    @property
    def step_length(self) -> float:
        """Horizontal length of the position increment [m]."""
        return float(math.hypot(self.delta[0], self.delta[1]))

    def placed(self, position: np.ndarray, heading: float, delta: np.ndarray) -> Stance:
        """This stance with another ``position`` [m NED], ``heading`` [rad] and ``delta`` [m] (another frame), the
        rest as it is (``dataclasses.replace`` without its generic field walk: once per stance on the engine's
        path)."""
        return Stance(self.t_start_s, self.t_end_s, position, heading, delta, self.peak_speed, self.samples,
                      self.mag_used, self.heading_sigma, self.pos_sigma, self.clipped)


def _none_u8() -> np.ndarray:
    return np.zeros(0, dtype=np.uint8)


def _none_f() -> np.ndarray:
    return np.zeros(0)


@dataclass
class NavOutput:
    """Per processed sample: ``t_s (n,)`` [s], ``pos (n,3)`` NED [m], ``vel (n,3)`` [m/s], ``heading (n,)``
    [rad] (NaN before alignment), ``zupt (n,)`` bool, ``statistic (n,)`` detector value; plus the stances
    that ended in this call; ``saturated (n,)`` uint8 the axes at the sensor's range (bits 0-2 accelerometer x, y,
    z, bits 3-5 gyroscope x, y, z: :data:`SAT_ACC`, :data:`SAT_GYR`), ``heading_sigma (n,)`` [rad] and
    ``pos_sigma (n,)`` [m] the 1-sigma heading and horizontal position uncertainty (NaN before alignment)."""

    t_s: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    heading: np.ndarray
    zupt: np.ndarray
    statistic: np.ndarray
    stances: list[Stance] = field(default_factory=list)
    saturated: np.ndarray = field(default_factory=_none_u8)
    heading_sigma: np.ndarray = field(default_factory=_none_f)
    pos_sigma: np.ndarray = field(default_factory=_none_f)

    @staticmethod
    def empty() -> NavOutput:
        z = np.zeros(0)
        return NavOutput(z, np.zeros((0, 3)), np.zeros((0, 3)), z.copy(), np.zeros(0, bool), z.copy(), [])

    @staticmethod
    def concatenate(parts: list[NavOutput]) -> NavOutput:
        """Join outputs of consecutive calls."""
        if not parts:
            return NavOutput.empty()
        return NavOutput(
            np.concatenate([p.t_s for p in parts]),
            np.concatenate([p.pos for p in parts]),
            np.concatenate([p.vel for p in parts]),
            np.concatenate([p.heading for p in parts]),
            np.concatenate([p.zupt for p in parts]),
            np.concatenate([p.statistic for p in parts]),
            [s for p in parts for s in p.stances],
            np.concatenate([p.saturated for p in parts]),
            np.concatenate([p.heading_sigma for p in parts]),
            np.concatenate([p.pos_sigma for p in parts]),
        )


def _inputs_checked(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray | None,
                    t_last: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """``(t, acc, gyr, mag)`` as :meth:`ZuptNavigator.process` would check and convert them, when they are
    already C-contiguous float64 arrays of the right shapes, not empty, and pass its checks (one compiled pass,
    :func:`models._zupt_kernel.inputs_ok`); else None (the checks in Python then say what is wrong)."""
    for a in (t, acc, gyr) if mag is None else (t, acc, gyr, mag):
        if type(a) is not np.ndarray or a.dtype != np.float64 or not a.flags.c_contiguous:
            return None
    n = t.shape[0]
    if (n == 0 or t.ndim != 1 or acc.shape != (n, 3) or gyr.shape != (n, 3)
            or (mag is not None and mag.shape != (n, 3))):
        return None
    if mag is None:
        mag = np.full((n, 3), np.nan)
    return (t, acc, gyr, mag) if _k.inputs_ok(t, acc, gyr, mag, t_last) else None


def _check_array(name: str, a: np.ndarray, n: int, allow_nan: bool) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape != (n, 3):
        raise ValueError(f"{name}: expected shape ({n}, 3), got {a.shape}")
    if np.isfinite(a).all():  # the common case in one pass; else the checks below say what is wrong
        return np.ascontiguousarray(a)
    if np.isinf(a).any():
        raise ValueError(f"{name}: contains inf")
    if allow_nan:
        partial = np.isnan(a).any(axis=1) & ~np.isnan(a).all(axis=1)
        if partial.any():
            raise ValueError(f"{name}: row {int(np.argmax(partial))} is partly NaN (a row is a sample or all NaN)")
    elif np.isnan(a).any():
        raise ValueError(f"{name}: contains NaN at row {int(np.argmax(np.isnan(a).any(axis=1)))}")
    return np.ascontiguousarray(a)


_CONFIG_FIELDS = tuple(f.name for f in fields(ZuptConfig))  # (a state stores them; fields() per state is slow)


class ZuptNavigator:
    """Streaming ZUPT-aided MARG navigator for a foot-mounted sensor of any mounting.

    Parameters
    ----------
    config : ZuptConfig
        Tunables (defaults are the project's single configuration).
    mag_reference : ndarray (3,) or None
        Expected Earth field in NED [uT] (e.g. from :func:`models.magnetic.wmm_reference`); when None and
        the magnetometer is used, the field seen during the initial rest becomes the reference.
    """

    def __init__(self, config: ZuptConfig | None = None, mag_reference: np.ndarray | None = None) -> None:
        self.config = config if config is not None else ZuptConfig()
        self.config.validate()
        self._par = self.config.to_array()
        self._x = np.zeros(16)
        self._x[0] = 1.0
        self._P = np.zeros((15, 15))
        self._fs = np.zeros(_k.N_FS)
        self._is = np.zeros(_k.N_IS, dtype=np.int64)
        if mag_reference is not None:
            ref = np.asarray(mag_reference, dtype=np.float64).reshape(3)
            if not np.all(np.isfinite(ref)) or not 5.0 < np.linalg.norm(ref) < 200.0:
                raise ValueError(f"mag_reference: expected a finite NED field of 5-200 uT, got {ref}")
            self._fs[_k.FS["ref0"] : _k.FS["ref2"] + 1] = ref
            self._fs[_k.FS["ref_valid"]] = 1.0
        # the kernel's buffer: t, acc, gyr, mag, clipped axes per sample and the 1-sigma errors of their
        # (repaired) values, seen through the views _bt .. _bsig
        self._set_buffer(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)),
                         np.zeros(0, dtype=np.uint8), np.zeros((0, 6)))
        self._next = 0  # index in the buffer of the first unprocessed sample
        self._t_last = -math.inf
        self._clip = ClipRepair(self.config.saturation())
        self._config_state: dict[str, Any] | None = None  # the config's fields as a state stores them (read once)

    # ---- public state ---------------------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        return bool(self._is[_k.IS["initialised"]])

    @property
    def position(self) -> np.ndarray:
        """NED position [m] of the last processed sample."""
        return self._x[7:10].copy()

    @property
    def velocity(self) -> np.ndarray:
        """NED velocity [m/s]."""
        return self._x[4:7].copy()

    @property
    def quaternion(self) -> np.ndarray:
        """Body-to-NED attitude quaternion ``[w, x, y, z]``."""
        return self._x[0:4].copy()

    @property
    def dcm(self) -> np.ndarray:
        """Body-to-NED DCM."""
        return _k.quat_dcm_s(self._x[0:4].copy())

    @property
    def heading(self) -> float:
        """Heading of the body x axis [rad], clockwise from north."""
        c = self.dcm
        return float(math.atan2(c[1, 0], c[0, 0]))

    @property
    def gyro_bias(self) -> np.ndarray:
        """Estimated gyroscope bias [rad/s]."""
        return self._x[13:16].copy()

    @property
    def acc_bias(self) -> np.ndarray:
        """Estimated accelerometer bias [m/s^2]."""
        return self._x[10:13].copy()

    @property
    def covariance(self) -> np.ndarray:
        """15x15 error-state covariance (004 eq. 6 ordering: dp, dv, phi, dba, dbg)."""
        return self._P.copy()

    @property
    def in_stance(self) -> bool:
        return bool(self._is[_k.IS["in_stance"]])

    @property
    def aligned_at_s(self) -> float:
        """Time of the initial alignment [s] (end of the rest or of the first stance of a mid-walk start);
        NaN before it."""
        return float(self._fs[_k.FS["t_align"]]) if self.initialised else math.nan

    @property
    def mid_walk_start(self) -> bool:
        """The foot was swinging before any rest: the alignment waits for (or was made on) a walking stance."""
        return bool(self._fs[_k.FS["moved"]])

    @property
    def gaps(self) -> tuple[int, int]:
        """Gaps in the data so far: ``(bridged, held)`` (up to and beyond ``gap_max_s``)."""
        return int(self._fs[_k.FS["n_bridged"]]), int(self._fs[_k.FS["n_coasted"]])

    # ---- processing -----------------------------------------------------------------------------------
    def process(self, t_s: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray | None = None) -> NavOutput:
        """Feed samples; returns the outputs of every sample whose detector window is now complete.

        Parameters
        ----------
        t_s : ndarray (N,)
            Sample times [s since session start], strictly increasing across calls.
        acc : ndarray (N, 3)
            Specific force [m/s^2], body frame.
        gyr : ndarray (N, 3)
            Angular rate [rad/s], body frame.
        mag : ndarray (N, 3) or None
            Magnetic field [uT], body frame; NaN rows = no magnetometer sample at that time.
        """
        fast = _inputs_checked(t_s, acc, gyr, mag, self._t_last)
        if fast is not None:  # the common case: arrays as the checks below would pass and convert them
            self._t_last = float(fast[0][-1])
            self._clip.push_into(*fast, self._rows)
            self._views()
            return self._run(final=False)
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        n = t.shape[0]
        if not np.all(np.isfinite(t)):
            raise ValueError("t_s: contains NaN or inf")
        if n and (np.any(np.diff(t) <= 0) or t[0] <= self._t_last):
            bad = "duplicated" if (np.any(np.diff(t) == 0) or (n and t[0] == self._t_last)) else "non-monotonic"
            raise ValueError(f"t_s: {bad} timestamps (must be strictly increasing across calls)")
        acc = _check_array("acc", acc, n, allow_nan=False)
        gyr = _check_array("gyr", gyr, n, allow_nan=False)
        mag = np.full((n, 3), np.nan) if mag is None else _check_array("mag", mag, n, allow_nan=True)
        if n == 0:
            return NavOutput.empty()
        self._t_last = float(t[-1])
        self._clip.push_into(t, acc, gyr, mag, self._rows)
        self._views()
        return self._run(final=False)

    def _set_buffer(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray, sat: np.ndarray,
                    sig: np.ndarray) -> None:
        """The buffer becomes these rows (the arrays are its storage from now on)."""
        self._rows = RowBuffer(t, acc, gyr, mag, sat, sig)
        self._views()

    def _views(self) -> None:
        self._bt, self._ba, self._bg, self._bm, self._bs, self._bsig = self._rows.views()

    def flush(self) -> NavOutput:
        """End of recording: process the samples held back for the detector's look-ahead (and the clipping
        repair's)."""
        e = np.zeros((0, 3))
        self._clip.push_into(np.zeros(0), e, e, e, self._rows, final=True)
        self._views()
        return self._run(final=True)

    def _run(self, final: bool) -> NavOutput:
        n_buf = self._bt.shape[0]
        m = n_buf - self._next
        if m <= 0:
            return NavOutput.empty()
        o_pos = np.empty((m, 3))
        o_vel = np.empty((m, 3))
        o_head = np.empty(m)
        o_zupt = np.zeros(m, dtype=np.bool_)
        o_stat = np.empty(m)
        o_sat = np.zeros(m, dtype=np.uint8)
        o_hsig = np.empty(m)
        o_psig = np.empty(m)
        st = np.empty((m // 2 + 2, _k.N_ST))
        nxt, n_st = _k.run_kernel(
            self._bt, self._ba, self._bg, self._bm, self._bs, self._bsig, self._next, final, self._x, self._P, self._fs, self._is,
            self._par, o_pos, o_vel, o_head, o_zupt, o_stat, o_sat, o_hsig, o_psig, st,
        )
        k = nxt - self._next
        out = NavOutput(
            self._bt[self._next : nxt].copy(), o_pos[:k], o_vel[:k], o_head[:k], o_zupt[:k], o_stat[:k],
            [
                Stance(r[0], r[1], np.array(r[2:5]), r[5], np.array(r[6:9]), r[9], int(r[10]), bool(r[11]), r[12],
                       r[13], int(r[14]))
                for r in st[:n_st].tolist()  # (Python floats: the same values as float() of each element)
            ] if n_st else [],
            o_sat[:k], o_hsig[:k], o_psig[:k],
        )
        self._next = nxt
        self._trim()
        return out

    def _trim(self) -> None:
        """Drop samples no longer needed as detector history (keeps the buffer short)."""
        if self._next == 0:
            return
        t = self._bt
        if self._next < t.shape[0]:
            tn = t[self._next]
        else:
            tn = t[-1]  # everything processed: the next sample's window starts after t[-1] - half window
        # detector windows reach back half_window_s + erosion_s (and one extra sample per window level)
        keep = int(t.searchsorted(tn - self.config.half_window_s - self.config.erosion_s, "left"))
        keep = max(min(keep, self._next) - 2, 0)
        if keep:
            self._rows.drop(keep)
            self._views()
            self._next -= keep

    def run(self, t_s: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray | None = None) -> NavOutput:
        """Convenience: ``process`` a whole recording and ``flush``; returns the joined output."""
        return NavOutput.concatenate([self.process(t_s, acc, gyr, mag), self.flush()])

    # ---- re-initialisation ----------------------------------------------------------------------------
    def reset(self, position_ned: np.ndarray, heading_rad: float) -> None:
        """Re-initialise at a stance: position [m NED], heading [rad]; tilt and biases are kept.

        Used when the scheduler comes back from gait dead reckoning. Velocity is set to zero; position and
        heading uncertainties are reset to small values.
        """
        p = np.asarray(position_ned, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(p)) or not math.isfinite(heading_rad):
            raise ValueError("reset: position and heading must be finite")
        c = self.dcm
        dpsi = heading_rad - math.atan2(c[1, 0], c[0, 0])
        qz = np.array([math.cos(dpsi / 2), 0.0, 0.0, math.sin(dpsi / 2)])
        self._x[0:4] = _k.quat_mul_s(qz, self._x[0:4].copy())
        self._x[4:7] = 0.0
        self._x[7:10] = p
        fsi = _k.FS
        self._fs[fsi["prev_n"] : fsi["prev_d"] + 1] = p
        self._fs[fsi["peak_speed"]] = 0.0
        self._fs[fsi["hdr_n"]] = 0.0  # a new straight segment starts (dominant directions are kept)
        self._fs[fsi["hdr_free_ok"]] = 0.0  # the heading jumped: not a turn of the foot
        self._fs[fsi["hdr_corr"]] = 0.0
        self._P[0:9, :] = 0.0
        self._P[:, 0:9] = 0.0
        for k in range(3):
            self._P[k, k] = 1e-6
            self._P[3 + k, 3 + k] = 1e-4
        self._P[6, 6] = self._P[7, 7] = self.config.p0_tilt**2
        self._P[8, 8] = self.config.p0_yaw**2

    @property
    def dominant_ref(self) -> float | None:
        """Heading [rad] of the building's dominant directions (``dom_on``: ``ref + k * 90 deg``, the body x axis
        of the first straight segment), None before one is known."""
        fsi = _k.FS
        return float(self._fs[fsi["dom_ref"]]) if self._fs[fsi["dom_valid"]] == 1.0 else None

    def turn_dominant(self, delta_rad: float) -> None:
        """Turn the building's dominant directions (``dom_on``) by ``delta_rad`` [rad] about the vertical.

        For a host that turns this navigator's output into its own frame by an angle that changes (the energy
        engine's ``_yaw``: a turn the gyroscope missed before a segment began): the snap keeps the host frame's
        directions when the host's turn changes by ``-delta_rad``. Nothing happens before they are known.
        """
        if not math.isfinite(delta_rad):
            raise ValueError("turn_dominant: delta_rad must be finite")
        fsi = _k.FS
        if self._fs[fsi["dom_valid"]] == 1.0:
            self._fs[fsi["dom_ref"]] = math.remainder(float(self._fs[fsi["dom_ref"]]) + delta_rad, 2.0 * math.pi)

    def restart(self, position_ned: np.ndarray, heading_rad: float, acc_rest: np.ndarray | None = None) -> None:
        """Begin a new segment after a gap in the data (the gyroscope was off), at a stance.

        Like :meth:`reset`, and the detector also forgets everything before the gap (buffered samples, stance
        state, gait intensity), so no stance or detector window spans the gap; its first stance reports a zero
        increment. Biases and the magnetic reference are kept; with ``acc_rest`` (mean specific force over the
        quiet samples the segment starts with [m/s^2], body frame) roll and pitch are re-levelled from it
        (001 eq. 1-3), otherwise the attitude of the last stance is kept.
        """
        if acc_rest is not None:
            self._x[0:4] = dcm_to_quat(align_at_rest(acc_rest))
        self.reset(position_ned, heading_rad)
        self._set_buffer(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)),
                         np.zeros(0, dtype=np.uint8), np.zeros((0, 6)))
        self._clip.reset()
        self._next = 0
        for name in ("in_stance", "has_prev", "has_prev_stance"):
            self._is[_k.IS[name]] = 0
        self._fs[_k.FS["intensity"]] = 0.0

    # ---- state ------------------------------------------------------------------------------------------
    def get_state(self) -> dict:
        """Complete state as plain values and numpy arrays (for :mod:`energy.codec`)."""
        if self._config_state is None:  # (frozen config: its ~75 fields read at the first state only)
            self._config_state = {name: getattr(self.config, name) for name in _CONFIG_FIELDS}
        return {
            "version": 1,
            "config": dict(self._config_state),  # flat: no deep copy
            "x": self._x.copy(),
            "P": self._P.copy(),
            "fs": self._fs.copy(),
            "is": self._is.copy(),
            "buf_t": self._bt.copy(),
            "buf_acc": self._ba.copy(),
            "buf_gyr": self._bg.copy(),
            "buf_mag": self._bm.copy(),
            "buf_sat": self._bs.copy(),
            "buf_sat_sigma": self._bsig.copy(),
            "clip": self._clip.get_state(),
            "next": int(self._next),
            "t_last": float(self._t_last) if math.isfinite(self._t_last) else None,
        }

    @classmethod
    def from_state(cls, d: dict) -> ZuptNavigator:
        """Rebuild a navigator from :meth:`get_state` output."""
        if d.get("version") != 1:
            raise ValueError(f"ZuptNavigator state: unsupported version {d.get('version')!r}")
        nav = cls(ZuptConfig(**d["config"]))
        nav._x = np.array(d["x"], dtype=np.float64).reshape(16)
        nav._P = np.array(d["P"], dtype=np.float64).reshape(15, 15)
        fs = np.array(d["fs"], dtype=np.float64).reshape(-1)
        if fs.size > _k.N_FS:
            raise ValueError(f"ZuptNavigator state: fs has {fs.size} entries, expected at most {_k.N_FS}")
        nav._fs = np.zeros(_k.N_FS)
        nav._fs[: fs.size] = fs  # states saved before newer float-state entries were added restore with zeros
        nav._is = np.array(d["is"], dtype=np.int64).reshape(_k.N_IS)
        bt = np.array(d["buf_t"], dtype=np.float64).reshape(-1)
        n = bt.shape[0]
        # states saved before range clipping was repaired: nothing flagged, nothing held back
        nav._set_buffer(
            bt,
            np.array(d["buf_acc"], dtype=np.float64).reshape(-1, 3),
            np.array(d["buf_gyr"], dtype=np.float64).reshape(-1, 3),
            np.array(d["buf_mag"], dtype=np.float64).reshape(-1, 3),
            np.array(d.get("buf_sat", np.zeros(n)), dtype=np.uint8).reshape(n),
            np.array(d.get("buf_sat_sigma", np.zeros((n, 6))), dtype=np.float64).reshape(n, 6),
        )
        if "clip" in d:
            nav._clip = ClipRepair.from_state(nav.config.saturation(), d["clip"])
        nav._next = int(d["next"])
        nav._t_last = -math.inf if d["t_last"] is None else float(d["t_last"])
        return nav

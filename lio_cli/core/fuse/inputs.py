"""What ``lio fuse`` estimates from: one plain dataclass of numpy arrays per source, and the options.

Conventions (DESIGN.md): stamps are int64 ns on one common clock (the caller applies clock offsets);
poses ``T_a_b`` (4,4); quaternions xyzw; world z up, g = (0, 0, -9.81). A value that a message does not
carry is NaN (a velocity component, a yaw rate) or masked out (``orientation_valid``, ``GpsSeries.valid``).
A covariance or sigma that is NaN, zero or negative (ROS writes 0 for "unknown" and -1 for "absent") is
replaced by the default noise of ``NoiseOptions`` and counted; ``use_message_covariance=False`` ignores
message covariances altogether. The series need not be sorted or clean: ``sanitize`` sorts them, drops
duplicated stamps and NaN rows and counts each case.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...errors import ConfigError
from .start_state import Start
from .wheel_yaw import Weighed

ESTIMATORS = ("auto", "ekf", "planar", "complementary")  # auto: chosen from the data (choose.py)

# measurement names per source (FuseOptions.use)
MEASUREMENTS: dict[str, tuple[str, ...]] = {
    "imu": ("gyro", "accel", "orientation"),
    # speed: forward speed plus the non-holonomic constraint (no lateral or vertical body speed);
    # velocity: every body-velocity component the message carries, no constraint (drones, holonomic bases)
    "wheel": ("speed", "velocity", "yaw_rate"),
    # pose: absolute poses in the odometry's world; delta: increments between consecutive poses
    "odom": ("pose", "delta"),
    "gps": ("position",),
}


@dataclass
class ImuSeries:
    """IMU samples. ``gyro_radps``/``accel_mps2`` (N,3) in the IMU frame (specific force: about +9.81 up at
    rest); ``orientation_xyzw`` (N,4) the IMU's own estimate ``R_world_imu`` where ``orientation_valid``;
    ``orientation_cov`` (N,3,3) rad^2 about the world axes (ROS convention)."""

    stamps_ns: np.ndarray
    gyro_radps: np.ndarray
    accel_mps2: np.ndarray
    T_base_imu: np.ndarray = field(default_factory=lambda: np.eye(4))
    orientation_xyzw: np.ndarray | None = None
    orientation_valid: np.ndarray | None = None
    orientation_cov: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.stamps_ns)


@dataclass
class WheelSeries:
    """Wheel odometry twist of the base frame (nav_msgs/Odometry or TwistStamped; twist-only is normal).

    ``velocity_mps`` (N,3) body-frame linear velocity, NaN where a component is absent; ``yaw_rate_radps``
    (N,) NaN where absent; optional variances ``velocity_var`` (N,3) and ``yaw_rate_var`` (N,);
    ``speed_scale_sigma``: how well a calibration knows the speed's scale (relative), where one scaled it."""

    stamps_ns: np.ndarray
    velocity_mps: np.ndarray
    yaw_rate_radps: np.ndarray
    velocity_var: np.ndarray | None = None
    yaw_rate_var: np.ndarray | None = None
    speed_scale_sigma: float | None = None

    def __len__(self) -> int:
        return len(self.stamps_ns)


@dataclass
class PoseSeries:
    """Poses ``T_odomworld_base`` (N,4,4) from LiDAR (or other) odometry, with optional per-pose sigmas
    ``position_sigma_m`` (N,) and ``rotation_sigma_rad`` (N,) (isotropic; an increment between two poses
    gets the sum of both poses' variances)."""

    stamps_ns: np.ndarray
    poses: np.ndarray
    position_sigma_m: np.ndarray | None = None
    rotation_sigma_rad: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.stamps_ns)


def at_antenna(R: np.ndarray, p: np.ndarray, lever: np.ndarray | None) -> np.ndarray:
    """The antenna's world position ``p + R a`` of base rotations ``R`` ((3,3) or (N,3,3)) and positions ``p``;
    ``p`` itself where ``lever`` is None (the antenna at the base origin)."""
    return p if lever is None else p + R @ lever


@dataclass
class GpsSeries:
    """GPS fixes already converted to a local ENU frame (metres): ``position_enu_m`` (N,3), ``cov_m2``
    (N,3,3), ``valid`` (N,) (fix status). Filled in on ``Prepared.gps`` (``gps_quality.assess_gps``), for
    every estimator alike: ``sigma_h_m``, ``sigma_v_m`` (N,) the horizontal and vertical sigma each fix is
    trusted with, ``accepted`` (N,) False for a fix left out (a multipath jump)."""

    stamps_ns: np.ndarray
    position_enu_m: np.ndarray
    cov_m2: np.ndarray | None = None
    valid: np.ndarray | None = None
    sigma_h_m: np.ndarray | None = None
    sigma_v_m: np.ndarray | None = None
    accepted: np.ndarray | None = None
    antenna_m: np.ndarray | None = None  # (3,) the antenna in base axes (/tf_static); None: at the base origin

    def __len__(self) -> int:
        return len(self.stamps_ns)

    @property
    def lever(self) -> np.ndarray | None:
        """The antenna's offset from the base origin (base axes), None where it is (within a millimetre)."""
        a = self.antenna_m
        return None if a is None or float(np.linalg.norm(a)) < 1e-3 else np.asarray(a, float)


@dataclass
class FuseInputs:
    """The sources of one fusion run; each optional, but at least one motion source (IMU, wheel, odom)."""

    imu: ImuSeries | None = None
    wheel: WheelSeries | None = None
    odom: PoseSeries | None = None
    gps: GpsSeries | None = None

    def present(self) -> dict[str, object]:
        return {k: v for k, v in (("imu", self.imu), ("wheel", self.wheel), ("odom", self.odom),
                                  ("gps", self.gps)) if v is not None and len(v) > 0}


@dataclass
class NoiseOptions:
    """Noise model. IMU values are continuous-time densities (per sqrt(Hz)), as ``lio calibrate`` writes.
    Sigmas are the defaults for messages without a usable covariance; ``use_message_covariance=False``
    applies them to every message."""

    gyro_noise_density: float = 1.0e-3  # rad/s/sqrt(Hz)
    accel_noise_density: float = 5.0e-2  # m/s^2/sqrt(Hz); a few times a MEMS datasheet: vehicle vibration
    gyro_bias_walk: float = 1.0e-4  # rad/s^2/sqrt(Hz)
    accel_bias_walk: float = 1.0e-3  # m/s^3/sqrt(Hz)
    # motion model without an IMU (and inside IMU gaps): white acceleration / angular acceleration densities
    cv_accel_density: float = 1.0  # m/s^2/sqrt(Hz)
    cv_angular_accel_density: float = 1.0  # rad/s^2/sqrt(Hz)
    wheel_speed_sigma_mps: float = 0.05
    wheel_speed_rel_sigma: float = 0.02  # plus this share of the speed (scale errors grow with it)
    wheel_yaw_rate_sigma_radps: float = 0.05
    nonholonomic_sigma_mps: float = 0.05  # lateral and vertical body speed of a wheeled base
    nonholonomic_rel_sigma: float = 0.03  # plus this share of the forward speed (body pitch, slip angle)
    odom_position_sigma_m: float = 0.02
    odom_rotation_sigma_rad: float = 0.005
    gps_position_sigma_m: float = 2.0  # horizontal
    gps_vertical_sigma_m: float = 5.0  # a receiver's altitude is several times worse than its position
    orientation_sigma_rad: float = 0.02
    use_message_covariance: bool = True
    # initial uncertainty
    init_velocity_sigma_mps: float = 1.0
    init_tilt_sigma_rad: float = 0.05
    init_gyro_bias_sigma_radps: float = 0.01
    init_accel_bias_sigma_mps2: float = 0.2


@dataclass
class FuseOptions:
    """Which measurement of which source enters, the noise, the estimator and the output stamps.

    ``use``: source -> set of measurement names (``MEASUREMENTS``); ``None`` picks per source present: IMU
    gyro and accel, plus orientation where the messages carry one; wheel speed, plus the wheel yaw rate
    only without an IMU (a gyro is far better; skid and baseline errors bias wheel yaw rates); odometry
    poses, or increments (delta) when GPS is used too; GPS position.
    ``weigh_wheel_yaw``: beside a gyro, the wheels' yaw rate weighed against it over the log and used where the
    data show it agrees, with the noise they show (``wheel_yaw``); ``None``: when ``use`` is None. ``wheel_yaw``:
    a weighing already made over the whole log (a run fused in pieces), used instead of weighing the piece.
    ``start``: the first state handed over by the piece before; ``handover_ns``: where to hand the next one its own.
    ``test_gps_shape``: whether the GPS-free track is tested against the fixes (``agreement``); a log fused in
    pieces is tested once, whole (``judge_gps``), never piece by piece. ``gps_jumps_ns``: the stamps of the fixes
    in multipath jumps as the whole log's jump test found them, used instead of a piece's own test (which sees
    no jump that opened before the piece, and takes the track's return for one).
    ``smooth``: the whole log before and after each instant: the factor graph (``graph``) whenever the
    accelerometer is used, whatever the filter (its guard falls back on the chosen filter), else the RTS pass
    over the EKF (the complementary filter has none); ``False``: the filter alone.
    ``rate_hz``: output rate; ``None`` outputs at every IMU sample (every motion measurement without an IMU).
    ``stamps_ns``: explicit output stamps (overrides ``rate_hz``). Stamps in gaps of every motion source or
    outside the data are not output (counted in ``FuseResult.info``).
    ``gate_probability``: a measurement whose Mahalanobis distance exceeds the chi-square quantile of
    ``1 - gate_probability`` is rejected as an outlier (``0`` disables the gate); after
    ``gate_max_rejects`` rejections in a row of one measurement kind the next one is accepted with the
    covariance of the states it touches inflated (the filter, not the sensor, is assumed wrong; a wheel body
    velocity inflates the velocity only, never the attitude its Jacobian reaches through ``[v_b]x``) and
    counted as ``gate_reset`` -- except a wheel yaw rate that disagrees with the gyro, never forced in, and a
    wheel speed while odometry poses or GPS are being accepted (``kalman.Anchor``: deferred until they lapse).
    ``gap_periods``: a pause longer than this many median sample periods of a source is a gap; it is
    bridged in one step of the constant-velocity model, never integrated sample by sample.
    ``snap_ns``: a wheel message stamped at most this far from an IMU sample is applied at that sample (one
    propagation step less per message on high-rate twist; the error is the motion over ``snap_ns``); 0
    applies every one at its own stamp.
    """

    estimator: str = "auto"
    smooth: bool = False  # the core's default is the filter alone; lio fuse and its config default to smoothing
    use: dict[str, set[str]] | None = None
    default_use: bool = False  # ``use`` is the default selection resolved (no --use): odometry's mode may follow
    weigh_wheel_yaw: bool | None = None
    wheel_yaw: Weighed | None = None  # the whole log's weighing (``whole_log_options``), applied here by stamp
    start: Start | None = None  # the first state, handed over by the piece before (``pieces``)
    handover_ns: int | None = None  # the stamp whose state goes into ``info["handover"]`` for the next piece
    test_gps_shape: bool = True  # False: a piece of a log whose whole is tested (``api.judge_gps``)
    gps_jumps_ns: np.ndarray | None = None  # the fixes in jumps, as the whole log's test found them (``judge_gps``)
    noise: NoiseOptions = field(default_factory=NoiseOptions)
    rate_hz: float | None = None
    stamps_ns: np.ndarray | None = None
    gate_probability: float = 1e-4
    gate_max_rejects: int = 5
    gap_periods: float = 5.0
    min_gap_ns: int = 20_000_000
    snap_ns: int = 1_000_000
    gravity_mps2: float = 9.81
    standing_window_ns: int = 1_000_000_000
    # complementary filter weights (lecture: alpha ~ 0.98 on the scan-matching pose)
    alpha_odom: float = 0.98
    alpha_orientation: float = 0.02
    alpha_gps: float = 0.05
    want_covariance: bool = True

    def validate(self) -> None:
        """Raise ConfigError (one line) for an option no run could use."""
        if self.estimator not in ESTIMATORS:
            raise ConfigError(f"unknown estimator '{self.estimator}' (choose from {', '.join(ESTIMATORS)})")
        if self.rate_hz is not None and not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ConfigError(f"--rate must be a positive number of Hz, got {self.rate_hz}")
        for src, names in (self.use or {}).items():
            if src not in MEASUREMENTS:
                raise ConfigError(f"unknown source '{src}' in use (choose from {', '.join(MEASUREMENTS)})")
            bad = sorted(set(names) - set(MEASUREMENTS[src]))
            if bad:
                raise ConfigError(f"unknown {src} measurement '{bad[0]}' in use (choose from "
                                  f"{', '.join(MEASUREMENTS[src])})")
        use = self.use or {}
        if {"pose", "delta"} <= set(use.get("odom", ())):
            raise ConfigError("use odom pose or odom delta, not both")
        if "accel" in use.get("imu", ()) and "gyro" not in use.get("imu", ()):
            raise ConfigError("the IMU accelerometer needs the gyro too (use imu gyro,accel)")
        for name in ("alpha_odom", "alpha_orientation", "alpha_gps"):
            a = getattr(self, name)
            if not 0.0 <= a <= 1.0:
                raise ConfigError(f"{name} must lie in [0, 1], got {a}")
        if not 0.0 <= self.gate_probability < 1.0:
            raise ConfigError(f"gate_probability must lie in [0, 1), got {self.gate_probability}")
        if self.gap_periods <= 1.0:
            raise ConfigError(f"gap_periods must exceed 1, got {self.gap_periods}")


def resolve_use(inputs: FuseInputs, options: FuseOptions) -> dict[str, set[str]]:
    """The measurement selection of this run: ``options.use`` restricted to the sources present, or the
    default selection (see ``FuseOptions``)."""
    present = inputs.present()
    if options.use is not None:
        return {s: set(m) for s, m in options.use.items() if s in present and m}
    out: dict[str, set[str]] = {}
    if "imu" in present:
        imu = inputs.imu
        out["imu"] = {"gyro", "accel"}
        if imu.orientation_xyzw is not None and (imu.orientation_valid is None or np.any(imu.orientation_valid)):
            out["imu"].add("orientation")
    if "wheel" in present:  # a wheel yaw rate only without a gyro: it is far worse (slip, baseline error)
        out["wheel"] = {"speed"} if "imu" in present else {"speed", "yaw_rate"}
    if "odom" in present:  # increments when GPS holds the absolute position, else absolute poses
        out["odom"] = {"delta"} if "gps" in present else {"pose"}
    if "gps" in present:
        out["gps"] = {"position"}
    return out

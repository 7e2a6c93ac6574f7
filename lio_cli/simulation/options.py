"""What a ``lio simulate`` run depends on besides scenario, duration and seed, and the checks on it.

Every field has a default that reproduces the logs made before the field existed, byte for byte; the
fields added for real-log conditions (start state, IMU mounting, ground-truth topic, start order of the
drivers, extrinsics in the log, wheels, GPS, stops mid-log, hills) are listed in :data:`CONDITION_DEFAULTS`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from ..errors import ConfigError
from .stops import check_stops
from .terrain import check_hills

TIME_CONVENTIONS = ("velodyne", "ouster", "livox", "hesai")
STARTS = ("still", "moving", "accelerating")
STILL_REST_S = 1.5  # --start still: at rest this long before the platform moves off
GT_TYPES = ("pose", "odometry", "none")
MAX_TILT_SCALE = 5.0  # the handheld's sway then reaches +-26 deg of pitch
MAX_DURATION_S = 3600.0  # ray-cast scenarios: simulate longer runs in pieces
MAX_STATIC_DURATION_S = 48 * 3600.0  # the IMU-only static scenario streams; hours are its purpose
DEFAULT_GPS_ORIGIN = (48.137154, 11.576124, 519.0)  # lat deg, lon deg, ellipsoidal height m
GPS_MODELS = ("standard", "consumer")
GPS_COVARIANCES = ("true", "optimistic", "absent")


@dataclass
class SimulationOptions:
    """Everything a run depends on besides scenario, duration and seed.

    ``noise_scale`` multiplies every sensor noise, bias and walk (0: ideal sensors); ``wheel_errors`` False:
    exact radius/baseline, no slip. Explicit values (``accel_bias_mps2``, ``wheel_radius_scale`` ...) replace
    the drawn ones and are not scaled. Vectors are tuples: ``imu_rotation_deg`` (roll, pitch, yaw) of
    ``R_base_imu = Rz(yaw) Ry(pitch) Rx(roll)``, ``imu_lever_arm_m`` the IMU origin in base, ``gps_origin``
    (lat deg, lon deg, WGS84 height m) of the world origin, ``gps_noise_m`` (east/north, up) 1-sigma.
    """

    beams: int | None = None
    columns: int | None = None
    imu_rate_hz: float = 200.0
    time_convention: str = "velodyne"
    header_stamp: str = "start"  # what a cloud's header stamp marks: the sweep's start or its end
    imu_time_offset_s: float = 0.0  # added to IMU stamps to put them on the LiDAR's clock (as a calibration's)
    noise_scale: float = 1.0
    range_noise_m: float | None = None
    dropout: float | None = None
    max_range_m: float | None = None
    accel_noise_density: float | None = None
    gyro_noise_density: float | None = None
    wheel_errors: bool = True
    # IMU error model beyond the noise densities
    accel_bias_walk: float | None = None
    gyro_bias_walk: float | None = None
    accel_bias_mps2: tuple[float, float, float] | None = None
    gyro_bias_radps: tuple[float, float, float] | None = None
    # wheel errors given explicitly (true = nominal * scale)
    wheel_radius_scale: tuple[float, float] | None = None
    wheel_baseline_scale: float | None = None
    # conditions of real recordings
    start: str = "still"
    tilt_scale: float = 1.0  # the platform's roll and pitch sway, times this
    imu_rotation_deg: tuple[float, float, float] | None = None
    imu_lever_arm_m: tuple[float, float, float] | None = None
    imu_start_delay_s: float = 0.0
    gt_type: str | None = None  # None: the scenario's (PoseStamped; static: none)
    gt_topic: str = "/ground_truth"
    gt_twist: bool = False
    tf_static: bool = True
    wheel: bool | None = None  # None: the scenario's
    gps: bool = False
    gps_rate_hz: float = 5.0
    gps_origin: tuple[float, float, float] = DEFAULT_GPS_ORIGIN
    gps_noise_m: tuple[float, float] | None = None  # None: the model's (standard 1, 2; consumer 2.5, 1.5)
    gps_outage_s: float | None = None  # None: min(10 s, 10% of the run)
    gps_invalid_fraction: float = 0.02
    # a consumer receiver's errors (None: the model's; standard: none, consumer: 25 m, 8 m, optimistic)
    gps_model: str = "standard"
    gps_alt_wander_m: float | None = None
    gps_jump_m: float | None = None
    gps_covariance: str | None = None
    wheel_slip_bursts: int = 0  # slip bursts on top of the error model's one episode (drawn from the seed)
    lidar: bool = True  # False: no LiDAR topic (a cheap log for IMU, wheel and GPS work)
    stops: tuple[tuple[float, float], ...] = ()  # (at_s, seconds) of each standstill mid-log, in time order
    hills: tuple[float, float] | None = None  # (amplitude_m, wavelength_m) of the ground along the path

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


CONDITION_DEFAULTS = {
    "start": "still", "tilt_scale": 1.0, "imu_rotation_deg": None, "imu_lever_arm_m": None, "imu_start_delay_s": 0.0,
    "gt_type": None, "gt_topic": "/ground_truth", "gt_twist": False, "tf_static": True, "wheel": None, "gps": False,
    "lidar": True, "stops": (), "hills": None,
}


def has_conditions(opts: SimulationOptions) -> bool:
    """True when any real-log condition departs from the historical default (truth.json then says which)."""
    return any(getattr(opts, k) != v for k, v in CONDITION_DEFAULTS.items())


def parse_floats(text: str | None, n: int, flag: str) -> tuple[float, ...] | None:
    """``"a,b,c"`` -> (a, b, c) with exactly ``n`` finite numbers, or a ConfigError naming ``flag``."""
    if text is None:
        return None
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise ConfigError(f"{flag} needs {n} comma-separated numbers (got '{text}')")
    return vals


_FLAGS = {"imu_rate_hz": "--imu-rate", "imu_time_offset_s": "--imu-time-offset", "range_noise_m": "--range-noise",
          "max_range_m": "--max-range", "accel_noise_density": "--accel-noise", "gyro_noise_density": "--gyro-noise",
          "accel_bias_walk": "--accel-walk", "gyro_bias_walk": "--gyro-walk", "accel_bias_mps2": "--accel-bias",
          "gyro_bias_radps": "--gyro-bias", "imu_rotation_deg": "--imu-rotation", "imu_lever_arm_m": "--imu-lever-arm",
          "imu_start_delay_s": "--imu-start-delay", "gps_rate_hz": "--gps-rate", "gps_noise_m": "--gps-noise",
          "gps_outage_s": "--gps-outage", "gps_invalid_fraction": "--gps-invalid", "tilt_scale": "--tilt-scale",
          "gps_alt_wander_m": "--gps-alt-wander", "gps_jump_m": "--gps-jump", "wheel_slip_bursts": "--wheel-slip-bursts",
          "stops": "--stop", "hills": "--hills"}


def validate(opts: SimulationOptions, scenario: str, duration_s: float) -> None:
    """One ConfigError line for the first option that cannot work; puts ``opts.stops`` in time order and
    makes ``opts.hills`` a float pair."""
    static = scenario == "static"
    limit = MAX_STATIC_DURATION_S if static else MAX_DURATION_S
    if not (duration_s > 0 and math.isfinite(duration_s)):
        raise ConfigError(f"--duration must be positive (got {duration_s})")
    if duration_s > limit:
        raise ConfigError(f"--duration {duration_s} s is more than {'48 hours' if static else 'an hour'}; "
                          "simulate shorter pieces")
    for f in fields(opts):  # every number given must be finite before any range check can mean anything
        value = getattr(opts, f.name)
        values = value if isinstance(value, tuple) else (value,)
        if any(isinstance(v, float) and not math.isfinite(v) for v in values):
            raise ConfigError(f"{_FLAGS.get(f.name, '--' + f.name.replace('_', '-'))} must be a finite number "
                              f"(got {value})")
    if opts.time_convention not in TIME_CONVENTIONS:
        raise ConfigError(f"unknown --time-convention '{opts.time_convention}' (choose from {', '.join(TIME_CONVENTIONS)})")
    if opts.header_stamp not in ("start", "end"):
        raise ConfigError(f"--header-stamp must be start or end (got '{opts.header_stamp}')")
    if opts.header_stamp == "end" and opts.time_convention in ("ouster", "livox"):
        raise ConfigError(f"--header-stamp end needs negative per-point offsets, which the {opts.time_convention} "
                          "convention (unsigned ns) cannot hold; use --time-convention velodyne or hesai")
    if opts.beams is not None and opts.beams not in (16, 32, 64, 128):
        raise ConfigError(f"--beams must be 16, 32, 64 or 128 (got {opts.beams})")
    if opts.columns is not None and not 16 <= opts.columns <= 4096:
        raise ConfigError(f"--columns must be between 16 and 4096 (got {opts.columns})")
    if not 10.0 <= opts.imu_rate_hz <= 2000.0:
        raise ConfigError(f"--imu-rate must be between 10 and 2000 Hz (got {opts.imu_rate_hz})")
    if opts.noise_scale < 0:
        raise ConfigError(f"--noise-scale must be >= 0 (got {opts.noise_scale})")
    if abs(opts.imu_time_offset_s) > 0.5:
        raise ConfigError(f"--imu-time-offset must be within +-0.5 s (got {opts.imu_time_offset_s})")
    if opts.range_noise_m is not None and not opts.range_noise_m >= 0.0:
        raise ConfigError(f"--range-noise must be >= 0 m (got {opts.range_noise_m})")
    if opts.max_range_m is not None and not 1.0 <= opts.max_range_m <= 1000.0:
        raise ConfigError(f"--max-range must be between 1 and 1000 m (got {opts.max_range_m})")
    for flag, value in (("--accel-noise", opts.accel_noise_density), ("--gyro-noise", opts.gyro_noise_density),
                        ("--accel-walk", opts.accel_bias_walk), ("--gyro-walk", opts.gyro_bias_walk)):
        if value is not None and not value >= 0.0:
            raise ConfigError(f"{flag} must be >= 0 (got {value})")
    if opts.dropout is not None and not 0.0 <= opts.dropout < 1.0:
        raise ConfigError(f"--dropout must be in [0, 1) (got {opts.dropout})")
    _validate_conditions(opts, scenario, duration_s)


def _validate_conditions(opts: SimulationOptions, scenario: str, duration_s: float) -> None:
    if opts.start not in STARTS:
        raise ConfigError(f"--start must be {', '.join(STARTS[:-1])} or {STARTS[-1]} (got '{opts.start}')")
    if not 0.0 <= opts.tilt_scale <= MAX_TILT_SCALE:
        raise ConfigError(f"--tilt-scale must be within 0..{MAX_TILT_SCALE:g} (got {opts.tilt_scale})")
    if opts.gt_type is not None and opts.gt_type not in GT_TYPES:
        raise ConfigError(f"--gt-type must be pose, odometry or none (got '{opts.gt_type}')")
    if not (opts.gt_topic.startswith("/") and len(opts.gt_topic) > 1 and " " not in opts.gt_topic):
        raise ConfigError(f"--gt-topic must be a topic name starting with / (got '{opts.gt_topic}')")
    if opts.gt_twist and opts.gt_type != "odometry":
        raise ConfigError("--gt-twist fills the twist of nav_msgs/Odometry ground truth; add --gt-type odometry")
    if not 0.0 <= opts.imu_start_delay_s < duration_s:
        raise ConfigError(f"--imu-start-delay must be >= 0 and shorter than the run (got {opts.imu_start_delay_s})")
    if opts.wheel_radius_scale is not None and not all(0.5 <= s <= 1.5 for s in opts.wheel_radius_scale):
        raise ConfigError(f"--wheel-radius-scale must be within 0.5..1.5 (got {','.join(map(str, opts.wheel_radius_scale))})")
    if opts.wheel_baseline_scale is not None and not 0.5 <= opts.wheel_baseline_scale <= 1.5:
        raise ConfigError(f"--wheel-baseline-scale must be within 0.5..1.5 (got {opts.wheel_baseline_scale})")
    if opts.gps:
        lat, lon, alt = opts.gps_origin
        if not (-90.0 < lat < 90.0 and -180.0 <= lon <= 180.0 and -1000.0 <= alt <= 10000.0):
            raise ConfigError(f"--gps-origin must be LAT,LON,ALT with |lat| < 90, |lon| <= 180, alt -1000..10000 m "
                              f"(got {','.join(map(str, opts.gps_origin))})")
        if not 0.1 <= opts.gps_rate_hz <= 100.0:
            raise ConfigError(f"--gps-rate must be between 0.1 and 100 Hz (got {opts.gps_rate_hz})")
        if opts.gps_noise_m is not None and not all(0.0 <= s <= 100.0 for s in opts.gps_noise_m):
            raise ConfigError(f"--gps-noise must be within 0..100 m (got {','.join(map(str, opts.gps_noise_m))})")
        if opts.gps_outage_s is not None and not 0.0 <= opts.gps_outage_s < duration_s:
            raise ConfigError(f"--gps-outage must be >= 0 and shorter than the run (got {opts.gps_outage_s})")
        if not 0.0 <= opts.gps_invalid_fraction < 1.0:
            raise ConfigError(f"--gps-invalid must be in [0, 1) (got {opts.gps_invalid_fraction})")
        if opts.gps_model not in GPS_MODELS:
            raise ConfigError(f"--gps-model must be standard or consumer (got '{opts.gps_model}')")
        if opts.gps_covariance is not None and opts.gps_covariance not in GPS_COVARIANCES:
            raise ConfigError(f"--gps-covariance must be true, optimistic or absent (got '{opts.gps_covariance}')")
        if opts.gps_alt_wander_m is not None and not 0.0 <= opts.gps_alt_wander_m <= 200.0:
            raise ConfigError(f"--gps-alt-wander must be within 0..200 m (got {opts.gps_alt_wander_m})")
        if opts.gps_jump_m is not None and not 0.0 <= opts.gps_jump_m <= 200.0:
            raise ConfigError(f"--gps-jump must be within 0..200 m (got {opts.gps_jump_m})")
    if not 0 <= opts.wheel_slip_bursts <= 100:
        raise ConfigError(f"--wheel-slip-bursts must be within 0..100 (got {opts.wheel_slip_bursts})")
    if scenario == "static":
        lidar_only = {"--beams": opts.beams, "--columns": opts.columns, "--range-noise": opts.range_noise_m,
                      "--dropout": opts.dropout, "--max-range": opts.max_range_m,
                      "--header-stamp": None if opts.header_stamp == "start" else opts.header_stamp,
                      "--imu-start-delay": opts.imu_start_delay_s or None, "--start": None if opts.start == "still" else opts.start,
                      "--tilt-scale": None if opts.tilt_scale == 1.0 else opts.tilt_scale,
                      "--wheel": opts.wheel or None, "--gps": opts.gps or None,
                      "--no-lidar": None if opts.lidar else True, "--stop": opts.stops or None,
                      "--hills": opts.hills}
        used = [flag for flag, v in lidar_only.items() if v is not None]
        if used:
            raise ConfigError(f"{used[0]} does not apply to the static scenario (an IMU at rest, no LiDAR, wheels or GPS)")
    elif scenario in ("handheld", "drone") and opts.wheel:
        raise ConfigError(f"--wheel: the {scenario} scenario has no wheels")
    if opts.wheel_slip_bursts and (scenario in ("handheld", "drone", "static") or opts.wheel is False):
        raise ConfigError("--wheel-slip-bursts needs wheels (drive, corridor, planar or rover, without --no-wheel)")
    if opts.stops:
        opts.stops = check_stops(opts.stops, STILL_REST_S if opts.start == "still" else 0.0, duration_s)
    if opts.hills is not None:
        opts.hills = check_hills(opts.hills, scenario, opts.lidar)

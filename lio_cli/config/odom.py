"""``lio odom``'s configuration: everything a run needs besides the log itself.

The ``.config.yaml`` a run writes is this model after resolution (topics chosen, base frame found, deskew
resolved), so ``lio odom LOG --config that.config.yaml`` repeats the run exactly.
"""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import Field

from ..model.calibration import Calibration
from . import MAX_COUNT, MAX_EVERY, MAX_ITERATIONS, MAX_POINTS, MAX_THREADS, Strict


class InputConfig(Strict):
    """Which parts of the log to read and how (None: detected; the resolved config names the topics and base
    frame used, but keeps ``format`` as asked: a detected format would bind the next log it is used with)."""

    format: Optional[Literal["ros1", "ros2", "mcap"]] = Field(None, description="log format; default: detected")
    lidar_topic: Optional[str] = Field(None, description="PointCloud2 or LaserScan topic; default: the only one")
    imu_topic: Optional[str] = Field(None, description="sensor_msgs/Imu topic; default: the only one")
    wheel_topic: Optional[str] = Field(None, description="wheel odometry topic; default: the only one")
    base_frame: Optional[str] = Field(None, description="base frame in /tf_static; default base_link, base or base_footprint")
    point_time: Optional[str] = Field(None, description="per-point time convention (as --point-time); default: detected")


class ImuNoise(Strict):
    """Continuous-time IMU noise densities and random walks (typical MEMS values)."""

    gyro_noise_radps: float = Field(2e-3, gt=0, description="gyro white noise, rad/s/sqrt(Hz)")
    accel_noise_mps2: float = Field(2e-2, gt=0, description="accel white noise, m/s^2/sqrt(Hz)")
    gyro_bias_walk: float = Field(5e-5, gt=0, description="gyro bias random walk, rad/s^2/sqrt(Hz)")
    accel_bias_walk: float = Field(1e-3, gt=0, description="accel bias random walk, m/s^3/sqrt(Hz)")


class RegistrationConfig(Strict):
    """kiss-icp registration and voxel map."""

    voxel_size_m: Optional[float] = Field(None, gt=0, description="map voxel size; default from the first scans' ranges")
    max_range_m: float = Field(100.0, gt=0, description="points farther from the LiDAR are dropped")
    min_range_m: float = Field(0.5, ge=0, description="points closer to the LiDAR (the platform itself) are dropped")
    source_voxel_factor: Optional[float] = Field(
        None, gt=0, description="registration keeps one point per voxel_size x this; default 2.5 in 3D, 1.5 (kiss-icp's) for 2D scans")
    max_source_points: Optional[int] = Field(
        None, gt=0, le=MAX_POINTS, description="registered points of a scan, about: a denser scan is voxelised again (ICP costs "
        "points x iterations; 600 halves a 32-128 beam car scan's ICP, at some accuracy); None: no limit")
    coarse_points: Optional[int] = Field(
        300, gt=0, le=MAX_POINTS, description="an IMU-primed scan registering more than twice this many points is first "
        "aligned with about this many (voxelised again), then refined with all of them in at most refine_iterations; "
        "None: always all points")
    refine_iterations: int = Field(5, gt=0, le=MAX_ITERATIONS, description="see coarse_points")
    gyro_prior_gate_m: Optional[float] = Field(
        None, gt=0, le=100.0, description="correspondence gate of a LiDAR-only scan primed by the gyro (None: 1 m)")
    max_points_per_voxel: int = Field(5, gt=0, le=1000, description="kiss-icp uses 20; 5 is faster and as accurate with an IMU prior")
    max_iterations: Optional[int] = Field(
        None, gt=0, le=MAX_ITERATIONS, description="ICP iterations per scan; default 20 with an IMU prior (it converges in a few), else 500")
    convergence: float = Field(1e-4, gt=0, description="ICP stops once an iteration's pose update is smaller")
    steady_iterations: Optional[int] = Field(
        None, gt=0, le=MAX_ITERATIONS, description="ICP iterations of IMU-primed scans once the online IMU clock estimate is done (None: "
        "max_iterations); lio deskew uses 5")
    slow_iterations: Optional[int] = Field(
        None, gt=0, le=MAX_ITERATIONS, description="ICP iterations of IMU-primed scans whose IMU turns slower than slow_rate_degps (None: "
        "as steady_iterations); lio deskew uses 2")
    slow_rate_degps: float = Field(5.0, ge=0, description="see slow_iterations")
    slow_register_every: int = Field(
        1, ge=1, le=4, description="of consecutive IMU-primed scans turning slower than slow_rate_degps, register only "
        "every n-th (once the map holds 20 scans, while the scene is far from degenerate); the others take the IMU "
        "prediction as their pose and stay out of the map (lio deskew uses 2 and de-skews them with the cubic "
        "through the registered poses)")
    initial_threshold_m: float = Field(2.0, gt=0, description="adaptive threshold's start (no IMU prior)")
    max_correspondence_m: Optional[float] = Field(
        None, gt=0, description="fixed correspondence distance; default: 0.5 m with an IMU prior, adaptive without")
    min_motion_m: float = Field(0.1, ge=0, description="adaptive threshold: only scans that moved this far update it")
    threads: int = Field(1, ge=0, le=MAX_THREADS, description=(
        "kiss-icp's threads; 1: the least CPU (a scan's few hundred to 1600 registered points are too few for "
        "threads to pay) and the same output every run; 0: all cores"))
    min_points: int = Field(50, gt=0, le=MAX_POINTS, description="scans with fewer valid points are skipped")


class FusionConfig(Strict):
    """How the registration result corrects the IMU state."""

    method: Literal["ekf", "complementary"] = Field("ekf", description="ekf (error-state) or complementary filter")
    alpha: float = Field(0.98, ge=0, le=1, description="complementary filter: weight of the scan match")
    position_sigma_m: float = Field(0.03, gt=0, description="registration position noise per scan")
    rotation_sigma_rad: float = Field(0.005, gt=0, description="registration rotation noise per scan")
    degenerate_sigma_m: float = Field(2.0, gt=0, description="position noise along a degenerate direction")
    degeneracy_ratio: float = Field(0.025, gt=0, description="horizontal eigenvalue ratio below which a direction is degenerate")
    degeneracy_every: int = Field(2, ge=1, le=MAX_EVERY, description="analyse the geometry every n-th scan, reuse it between")
    degeneracy_every_clear: int = Field(4, ge=1, le=MAX_EVERY, description=(
        "analyse it every n-th scan (rounded up to a multiple of degeneracy_every) while the last analysis found "
        "the weakest direction 4x above degeneracy_ratio"))
    wheel_beta: float = Field(0.5, ge=0, le=1, description="complementary filter: weight of the wheel speed")
    wheel_speed_sigma_mps: float = Field(0.2, gt=0, description="wheel speed noise (covers slip episodes)")
    imu: ImuNoise = ImuNoise()


class OdomConfig(Strict):
    """Everything ``lio odom`` can be told; flags override the YAML field by field."""

    input: InputConfig = InputConfig()
    calibration: Calibration = Field(Calibration(), description="used where /tf_static is silent (see --calib)")
    deskew: Literal["auto", "imu", "constant-velocity", "none"] = Field(
        "auto", description="auto: imu when the prior is imu, else constant-velocity (none when the prior is none)")
    prior: Literal["imu", "constant-velocity", "wheel", "none"] = Field(
        "imu", description="initial guess of each registration: imu, constant-velocity, wheel or none")
    use_wheel: bool = Field(True, description="join wheel odometry to the prediction when a wheel topic exists")
    scan_reference: Literal["end", "start"] = Field(
        "end", description="the instant of its scan each pose is de-skewed to and stamped with")
    frame: Literal["base", "lidar", "imu"] = Field("base", description="whose trajectory is written")
    planar: Optional[bool] = Field(None, description="force SE(2) mode; default: on for LaserScan input")
    init_window_s: float = Field(
        1.0, gt=0, le=60, description="LiDAR-only scans over this long start the IMU state (standing or moving start)")
    max_gap_s: float = Field(
        1.0, gt=0, description="a longer pause between scans is a time gap: bridged by the IMU state (see max_bridge_s), "
                               "else restarted from the LiDAR")
    max_bridge_s: float = Field(
        3.0, ge=0, description="a time gap up to this long that the IMU covers is bridged: the state is propagated across "
                               "it (with wheel speed) and the next scan registered from that prediction; 0: never")
    max_lost_scans: int = Field(20, ge=1, le=MAX_COUNT, description="LiDAR-only registration failing this many scans in a row ends the run (exit 1)")
    estimate_time_offset: bool = Field(
        True, description="estimate a small IMU-LiDAR clock offset while running (on top of the calibration's) and apply it")
    max_speed_mps: float = Field(70.0, gt=0, description="a faster IMU state is implausible and is started again from the LiDAR")
    gravity_mps2: float = Field(9.81, gt=0, le=30, description="magnitude of gravity, m/s^2")
    registration: RegistrationConfig = RegistrationConfig()
    fusion: FusionConfig = FusionConfig()

    def resolved_deskew(self) -> str:
        """``deskew`` with ``auto`` replaced by what it means for this prior."""
        if self.deskew != "auto":
            return self.deskew
        return {"imu": "imu", "none": "none"}.get(self.prior, "constant-velocity")


__all__ = ["FusionConfig", "ImuNoise", "InputConfig", "OdomConfig", "RegistrationConfig"]

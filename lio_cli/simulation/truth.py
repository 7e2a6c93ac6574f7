"""``x.truth.json``: everything true about a simulated run that a tool could estimate or must know.

A run without any real-log condition writes the base keys only. A run with any condition (``--start moving``,
``--tilt-scale``, ``--imu-rotation``, ``--gt-type``, ``--imu-start-delay``, ``--no-tf-static``,
``--wheel/--no-wheel``, ``--gps``, ``--stop``, ``--hills``) and every static run add a complete ``conditions``
block; GPS runs add ``gps``, runs with stops ``stops``, runs over hills ``hills``, static runs ``allan``.
``imu.imu_time_offset_s`` is added to IMU stamps to put them on the LiDAR's clock, as in a calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gps import GpsFixes, GpsSpec
from .motion import MotionState
from .options import SimulationOptions, has_conditions
from .record import TOPIC_GPS, TOPIC_IMU, TOPIC_POINTS, TOPIC_SCAN, TOPIC_WHEEL
from .scenarios import Scenario
from .sensors import NS, ImuData, ImuSpec, LidarSpec, beam_elevations_deg
from .stops import STOPS_MEANING, StoppedTrajectory, stops_truth
from .terrain import hills_truth


@dataclass
class RunFacts:
    """What the run did beyond its options: needed for truth.json."""

    gt_type: str
    gt_rate_hz: float
    first_imu_ns: int
    first_scan_header_ns: int | None
    initial: MotionState  # the base's state at the run's start (one row)
    gps: tuple[GpsSpec, GpsFixes] | None = None


def bias_stats(imu: ImuData) -> dict:
    """First, last and mean true IMU bias of a run held in memory."""
    return {"accel_first": imu.accel_bias_mps2[0], "gyro_first": imu.gyro_bias_radps[0],
            "accel_last": imu.accel_bias_mps2[-1], "gyro_last": imu.gyro_bias_radps[-1],
            "accel_mean": imu.accel_bias_mps2.mean(axis=0), "gyro_mean": imu.gyro_bias_radps.mean(axis=0)}


def _matrix(T: np.ndarray | None) -> list | None:
    return None if T is None else (np.round(T, 12) + 0.0).tolist()


def _lidar(sc: Scenario, opts: SimulationOptions) -> dict | None:
    lid = sc.lidar
    if lid is None or not opts.lidar:
        return None
    lidar = {"topic": TOPIC_POINTS if isinstance(lid, LidarSpec) else TOPIC_SCAN, "frame_id": "lidar",
             "period_s": lid.period_ns * 1e-9, "range_noise_m": lid.range_noise_m, "dropout": lid.dropout,
             "max_range_m": lid.max_range_m, "min_range_m": lid.min_range_m,
             "header_stamp_marks": opts.header_stamp if isinstance(lid, LidarSpec) else "start",
             "record_time": "scan end"}
    if isinstance(lid, LidarSpec):
        lidar.update(type="spinning", beams=lid.beams, columns=lid.columns, time_convention=opts.time_convention,
                     elevations_deg=np.round(beam_elevations_deg(lid.beams), 6).tolist())
    else:
        lidar.update(type="planar", beams=lid.beams, angle_min_rad=lid.angle_min_rad,
                     angle_increment_rad=lid.angle_increment_rad)
    return lidar


def _wheel(sc: Scenario, start_ns: int) -> dict | None:
    w = sc.wheels
    if w is None:
        return None
    slip = None
    if w.slip_start_s is not None and w.slip_duration_s > 0 and (w.slip_left or w.slip_right):
        slip = {"start_s": w.slip_start_s, "duration_s": w.slip_duration_s,
                "start_ns": start_ns + int(round(w.slip_start_s * NS)),
                "end_ns": start_ns + int(round((w.slip_start_s + w.slip_duration_s) * NS)),
                "left": w.slip_left, "right": w.slip_right,
                "meaning": "measured wheel speed = ground speed * (1 + slip) inside the window (raised-cosine edges)"}
    bursts = None
    if w.bursts:
        bursts = [{"start_s": b[0], "duration_s": b[1], "start_ns": start_ns + int(round(b[0] * NS)),
                   "end_ns": start_ns + int(round((b[0] + b[1]) * NS)), "left": b[2], "right": b[3]} for b in w.bursts]
    return {"topic": TOPIC_WHEEL, "rate_hz": w.rate_hz, "radius_m_nominal": w.radius_m,
            "baseline_m_nominal": w.baseline_m, "radius_scale_left": w.radius_scale_left,
            "radius_scale_right": w.radius_scale_right, "baseline_scale": w.baseline_scale,
            "scale_meaning": "true = nominal * scale; odometry uses the nominal values", "slip": slip,
            **({"slip_bursts": bursts, "slip_bursts_meaning": "as slip, added to it where they overlap"} if bursts else {})}


def _conditions(sc: Scenario, opts: SimulationOptions, facts: RunFacts) -> dict:
    st = facts.initial
    v_w, R = st.velocity_mps[0], st.R_world_base[0]
    return {
        "start": opts.start,
        "tilt_scale": opts.tilt_scale,
        "initial_state": {
            "meaning": "the base at start_ns, the first sample of every sensor (world frame unless named)",
            "T_world_base": _matrix(st.poses[0]), "velocity_mps": v_w.tolist(),
            "velocity_base_mps": (R.T @ v_w).tolist(), "speed_mps": float(np.linalg.norm(v_w)),
            "accel_mps2": st.accel_mps2[0].tolist(), "omega_base_radps": st.omega_base_radps[0].tolist(),
        },
        "imu_rotation_rpy_deg": None if opts.imu_rotation_deg is None else list(opts.imu_rotation_deg),
        "imu_lever_arm_m": sc.T_base_imu[:3, 3].tolist(),
        "imu_rotation_meaning": "R_base_imu = Rz(yaw) Ry(pitch) Rx(roll); null: the scenario's mounting (see T_base_imu)",
        "imu_start_delay_s": opts.imu_start_delay_s,
        "first_imu_stamp_ns": facts.first_imu_ns,
        "first_scan_header_ns": facts.first_scan_header_ns,
        "first_scan_before_first_imu": (facts.first_scan_header_ns is not None
                                        and facts.first_scan_header_ns < facts.first_imu_ns),
        "tf_static": opts.tf_static,
        "wheel": sc.wheels is not None,
        "ground_truth": {"type": facts.gt_type, "topic": None if facts.gt_type == "none" else opts.gt_topic,
                         "twist": None if facts.gt_type != "odometry" else ("true" if opts.gt_twist else "zero")},
        "gps": facts.gps is not None,
    }


def _gps(sc: Scenario, spec: GpsSpec, fixes: GpsFixes, start_ns: int) -> dict:
    valid = fixes.status == 0
    err = fixes.error_enu_m[valid]
    T_base_gps = np.eye(4)
    T_base_gps[:3, 3] = sc.gps_antenna_m
    outage = None
    if spec.outage_s > 0:
        t0 = start_ns + int(round(spec.outage_start_s * NS))
        outage = {"start_ns": t0, "end_ns": t0 + int(round(spec.outage_s * NS)), "duration_s": round(spec.outage_s, 9),
                  "meaning": "no messages in [start_ns, end_ns); the fixes just before and after are invalid"}
    lat, lon, alt = spec.origin
    return {
        "topic": TOPIC_GPS, "frame_id": "gps", "rate_hz": spec.rate_hz,
        "origin": {"lat_deg": lat, "lon_deg": lon, "alt_m": alt},
        "world_frame": "ENU about the origin: x east, y north, z up; altitude = WGS84 ellipsoidal height",
        "T_base_gps": _matrix(T_base_gps),
        "noise_m": {"east": spec.noise_m[0], "north": spec.noise_m[0], "up": spec.noise_m[1]},
        "error_model": {"gauss_markov_share": spec.correlated_share, "tau_s": spec.tau_s,
                        "meaning": "per axis: white noise + first-order Gauss-Markov, total 1-sigma = noise_m"},
        "reported_covariance_enu_m2": fixes.covariance_enu_m2.tolist(),
        "messages": int(len(fixes.stamps_ns)), "invalid": int((~valid).sum()),
        "invalid_stamps_ns": fixes.stamps_ns[~valid].tolist(),
        "invalid_meaning": "status -1 (no fix), latitude/longitude/altitude NaN, covariance type 0",
        "invalid_fraction": spec.invalid_fraction, "outage": outage,
        **_consumer(spec, fixes, start_ns),
        "error_rms_m": {"horizontal": float(np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1)))) if len(err) else None,
                        "up": float(np.sqrt(np.mean(err[:, 2] ** 2))) if len(err) else None},
    }


def _consumer(spec: GpsSpec, fixes: GpsFixes, start_ns: int) -> dict:
    """The receiver model's keys, only when it departs from the standard one (older truth files keep their bytes)."""
    if spec.model == "standard" and not spec.alt_wander_m and not spec.jump_m and spec.covariance == "true":
        return {}
    valid = fixes.status == 0
    wander = jump = None
    if fixes.wander_m is not None:
        w = fixes.wander_m[valid]
        wander = {"peak_to_peak_m": spec.alt_wander_m, "measured_peak_to_peak_m": float(w.max() - w.min()) if len(w) else None,
                  "meaning": "a slow smooth wander added to the up error, zero mean, this peak to peak over the run"}
    if fixes.jump_enu_m is not None:
        t0 = start_ns
        jump = {"size_m": spec.jump_m, "offset_enu_m": fixes.jump_enu_m.tolist(), "start_s": spec.jump_start_s,
                "duration_s": spec.jump_s, "start_ns": t0 + int(round(spec.jump_start_s * NS)),
                "end_ns": t0 + int(round((spec.jump_start_s + spec.jump_s) * NS)),
                "meaning": "multipath: every fix in [start_ns, end_ns) shifted by offset_enu_m"}
    return {"model": spec.model, "covariance": spec.covariance, "covariance_meaning":
            {"true": "the true white + Gauss-Markov sigmas", "optimistic": "a third of the true sigmas, no wander or jump",
             "absent": "type 0, all zeros"}[spec.covariance], "altitude_wander": wander, "multipath_jump": jump}


def _allan(spec: ImuSpec) -> dict:
    return {"accelerometer_noise_density": spec.accel_noise_density, "accelerometer_random_walk": spec.accel_bias_walk,
            "gyroscope_noise_density": spec.gyro_noise_density, "gyroscope_random_walk": spec.gyro_bias_walk,
            "bias_instability": 0.0, "units": "noise density per sqrt(Hz) (m/s^2, rad/s), random walk per s*sqrt(Hz)",
            "model": "per axis: allan_deviation(tau)^2 = noise_density^2 / tau + random_walk^2 * tau / 3 "
                     "(white noise + bias random walk; no bias instability, no earth rotation)"}


def truth_dict(sc: Scenario, opts: SimulationOptions, imu_spec: ImuSpec, bias: dict, seed: int, fmt: str,
               start_ns: int, end_ns: int, facts: RunFacts) -> dict:
    imu = {
        "topic": TOPIC_IMU, "frame_id": "imu", "rate_hz": imu_spec.rate_hz,
        "imu_time_offset_s": imu_spec.imu_time_offset_ns * 1e-9, "imu_time_offset_ns": imu_spec.imu_time_offset_ns,
        "imu_time_offset_meaning": "added to IMU stamps to put them on the LiDAR's clock (LiDAR and ground truth "
                                   "carry true time)",
        "accel_bias_mps2": bias["accel_first"].tolist(), "gyro_bias_radps": bias["gyro_first"].tolist(),
        "accel_bias_final_mps2": bias["accel_last"].tolist(), "gyro_bias_final_radps": bias["gyro_last"].tolist(),
        "accel_bias_mean_mps2": bias["accel_mean"].tolist(), "gyro_bias_mean_radps": bias["gyro_mean"].tolist(),
        "accel_noise_density": imu_spec.accel_noise_density, "gyro_noise_density": imu_spec.gyro_noise_density,
        "accel_bias_walk": imu_spec.accel_bias_walk, "gyro_bias_walk": imu_spec.gyro_bias_walk,
    }
    static = sc.lidar is None
    truth = {
        "scenario": sc.name, "description": sc.description, "seed": seed, "format": fmt,
        "start_ns": start_ns, "end_ns": end_ns, "duration_s": round((end_ns - start_ns) * 1e-9, 9),
        "gravity_mps2": [0.0, 0.0, -9.81],
        "frames": {"world": "fixed, z up; ground truth is T_world_base", "base": "x forward, y left, z up",
                   "odom": "wheel odometry origin = base pose at start"},
        "T_base_imu": _matrix(sc.T_base_imu), "T_base_lidar": _matrix(sc.T_base_lidar),
        "imu": imu, "lidar": _lidar(sc, opts), "wheel": _wheel(sc, start_ns),
        "ground_truth": {"topic": None if facts.gt_type == "none" else opts.gt_topic, "frame_id": "world",
                         "child": "base", "rate_hz": facts.gt_rate_hz},
        "noise_scale": opts.noise_scale, "rest_s": round((end_ns - start_ns) * 1e-9, 9) if static else sc.rest_s,
    }
    if has_conditions(opts) or static:
        truth["conditions"] = _conditions(sc, opts, facts)
        truth["ground_truth"].update(type=facts.gt_type, file="pose of base in world at rate_hz (x.gt.tum)")
    if opts.stops:
        truth.update(stops=stops_truth(opts.stops, start_ns), stops_meaning=STOPS_MEANING)
    if opts.hills is not None:
        motion = sc.trajectory.motion if isinstance(sc.trajectory, StoppedTrajectory) else sc.trajectory
        truth["hills"] = hills_truth(motion.terrain, float(motion.progress(np.array([0.0]))[0][0]))
    if facts.gps is not None:
        truth["gps"] = _gps(sc, *facts.gps, start_ns)
    if static:
        truth["allan"] = _allan(imu_spec)
    return truth

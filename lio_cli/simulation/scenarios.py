"""The scenarios: a world, a trajectory through it that never enters an obstacle, the sensor rig.

Worlds are fixed (their clutter comes from a fixed internal seed, placed away from the paths), so the
same scenario always happens in the same place; ``--seed`` only drives sensor noise and biases.

``start="still"``: the platform stands still for 1.5 s, then ramps up. ``start="moving"``: every ramp and
fade-in is over before t = 0, so each sensor's first sample already sees the full motion; the drive instead
starts cruising straight at 7.5 m/s with its sway fading in over 3 s, so its IMU first looks still.
``start="accelerating"``: every speed ramp is half done at t = 0, so the first samples see its largest
acceleration (the drive: 3.75 m/s and 3.75 m/s^2 on that straight, what reads as a 21 deg tilt to an IMU).
``rover`` is a wheeled robot outdoors on uneven ground (2D motion, small roll and pitch), ``drone`` a
multicopter over the same town (3D motion: it climbs and sinks by metres).
``static`` is an IMU at rest on a table for hours (no LiDAR, no wheels): the noise model alone.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..geometry import make_pose
from .motion import Path2D, Progress, Sines, Trajectory, ypr_to_matrix
from .options import STILL_REST_S
from .sensors import LaserSpec, LidarSpec, WheelSpec
from .stops import StoppedTrajectory
from .terrain import Hills
from .world import World, footprint_clearance

SCENARIOS = ("handheld", "drive", "corridor", "planar", "rover", "drone")  # the LiDAR scenarios
ALL_SCENARIOS = SCENARIOS + ("static",)

_WALL_M = 0.2
_STOREY_M = 2.8


@dataclass
class Scenario:
    name: str
    description: str
    world: World
    trajectory: Trajectory | StoppedTrajectory
    T_base_imu: np.ndarray
    T_base_lidar: np.ndarray | None
    lidar: LidarSpec | LaserSpec | None
    wheels: WheelSpec | None
    clearance_m: float  # the platform's half-width: the path keeps at least this from every obstacle
    body_z_m: tuple[float, float] = (0.0, 1.9)  # height band the platform occupies (for the clearance check)
    rest_s: float = 1.5  # standing still for this long at the start (0: moving from the first sample)
    gps_antenna_m: tuple[float, float, float] = (0.0, 0.0, 0.3)  # GPS antenna position in base


def _pose(rpy_rad: tuple[float, float, float], xyz_m: tuple[float, float, float]) -> np.ndarray:
    roll, pitch, yaw = rpy_rad
    return make_pose(ypr_to_matrix(np.array(yaw), np.array(pitch), np.array(roll)), np.asarray(xyz_m, float))


def _wall_x(world: World, y: float, x0: float, x1: float, doors: list[float], door_w: float = 1.2) -> None:
    """A wall along x at ``y`` from x0 to x1, with doorways (lintel above 2.1 m) centred at ``doors``."""
    edges = [x0]
    for d in sorted(doors):
        edges += [d - door_w / 2, d + door_w / 2]
        world.add_box((d - door_w / 2, y - _WALL_M / 2, 2.1), (d + door_w / 2, y + _WALL_M / 2, _STOREY_M), 0.6)
    edges.append(x1)
    for a, b in zip(edges[::2], edges[1::2]):
        world.add_box((a, y - _WALL_M / 2, 0.0), (b, y + _WALL_M / 2, _STOREY_M), 0.6)


def _wall_y(world: World, x: float, y0: float, y1: float) -> None:
    world.add_box((x - _WALL_M / 2, y0, 0.0), (x + _WALL_M / 2, y1, _STOREY_M), 0.6)


# Office floor: 36 x 16 m, a 3 m hallway (y 7..10) between four south rooms and three north rooms.
_HALL_Y = (7.0, 10.0)
_SOUTH_DOORS = [6.0, 13.5, 22.5, 31.5]
_NORTH_DOORS = [8.0, 18.0, 30.0]

HANDHELD_WAYPOINTS = np.array([
    (4.0, 3.6), (5.3, 5.0), (6.0, 6.1), (6.0, 7.0), (6.5, 8.2), (8.5, 8.6), (14.0, 8.4), (20.0, 8.7),
    (26.0, 8.5), (29.2, 8.9), (30.0, 10.0), (30.4, 11.6), (32.6, 13.2), (30.5, 14.8), (27.4, 13.6),
    (28.6, 11.6), (30.0, 10.0), (29.0, 8.6), (24.0, 8.3), (17.0, 8.6), (14.3, 8.2), (13.5, 7.0),
    (13.6, 5.6), (15.8, 3.6), (13.5, 1.6), (11.2, 3.6), (13.4, 5.6), (13.5, 7.0), (12.4, 8.5),
    (8.0, 8.7), (6.2, 8.2), (6.0, 7.0), (5.7, 5.6), (3.6, 2.2), (2.6, 2.8),
])

PLANAR_WAYPOINTS = np.array([
    (5.0, 13.0), (7.2, 11.6), (8.0, 10.0), (8.8, 8.5), (12.0, 8.2), (16.2, 8.4), (18.0, 10.0),
    (18.4, 11.8), (21.0, 13.4), (18.0, 14.6), (15.2, 13.2), (16.8, 11.5), (18.0, 10.0), (17.2, 8.7),
    (12.0, 8.6), (9.6, 8.9), (8.0, 10.0), (7.6, 12.4), (5.0, 14.6), (3.0, 13.6),
])


def office_world(keep_clear: list[np.ndarray], clear_m: float = 0.9, seed: int = 7) -> World:
    """Rooms, doorways, a long hallway, furniture and clutter; nothing within ``clear_m`` of the paths."""
    w = World("office")
    w.add_plane(0.0, 0.25)
    w.add_plane(_STOREY_M, 0.45)
    x0, x1, y0, y1 = 0.0, 36.0, 0.0, 16.0
    _wall_x(w, y0, x0, x1, [])
    _wall_x(w, y1, x0, x1, [])
    _wall_y(w, x0, y0, y1)
    _wall_y(w, x1, y0, y1)
    _wall_x(w, _HALL_Y[0], x0, x1, _SOUTH_DOORS)
    _wall_x(w, _HALL_Y[1], x0, x1, _NORTH_DOORS)
    for x in (9.0, 18.0, 27.0):
        _wall_y(w, x, y0, _HALL_Y[0])
    for x in (12.0, 24.0):
        _wall_y(w, x, _HALL_Y[1], y1)
    rng = np.random.default_rng(seed)
    path_xy = np.vstack(keep_clear)
    rooms = [(0, 9, 0, 7), (9, 18, 0, 7), (18, 27, 0, 7), (27, 36, 0, 7), (0, 12, 10, 16), (12, 24, 10, 16), (24, 36, 10, 16)]
    door_pts = np.array([(d, _HALL_Y[0]) for d in _SOUTH_DOORS] + [(d, _HALL_Y[1]) for d in _NORTH_DOORS])

    def free(lo, hi, margin):
        probe = World("probe")
        probe.add_box(lo, hi)
        pts = np.vstack([path_xy, door_pts])
        return footprint_clearance(probe, pts).min() > margin

    for rx0, rx1, ry0, ry1 in rooms:
        placed, tries = 0, 0
        while placed < 12 and tries < 500:
            tries += 1
            kind = rng.choice(["desk", "shelf", "cabinet", "box", "pillar", "bin"], p=[0.25, 0.2, 0.15, 0.2, 0.1, 0.1])
            if kind in ("pillar", "bin"):
                r = 0.2 if kind == "pillar" else 0.25
                cx, cy = rng.uniform(rx0 + 0.5, rx1 - 0.5), rng.uniform(ry0 + 0.5, ry1 - 0.5)
                if np.min(np.linalg.norm(np.vstack([path_xy, door_pts]) - (cx, cy), axis=1)) - r > clear_m:
                    w.add_cylinder(cx, cy, r, 0.0, _STOREY_M if kind == "pillar" else 0.7, 0.7 if kind == "bin" else 0.5)
                    placed += 1
                continue
            sx, sy, h = {"desk": (1.6, 0.8, 0.75), "shelf": (1.2, 0.4, 2.0), "cabinet": (0.8, 0.6, 1.2),
                         "box": (0.6, 0.5, 0.5)}[kind]
            if rng.random() < 0.5:
                sx, sy = sy, sx
            if kind == "shelf":  # against a wall
                side = rng.integers(4)
                cx = rng.uniform(rx0 + 1, rx1 - 1) if side < 2 else (rx0 + _WALL_M / 2 + sx / 2 if side == 2 else rx1 - _WALL_M / 2 - sx / 2)
                cy = (ry0 + _WALL_M / 2 + sy / 2 if side == 0 else ry1 - _WALL_M / 2 - sy / 2) if side < 2 else rng.uniform(ry0 + 1, ry1 - 1)
            else:
                cx, cy = rng.uniform(rx0 + 0.6, rx1 - 0.6), rng.uniform(ry0 + 0.6, ry1 - 0.6)
            lo, hi = (cx - sx / 2, cy - sy / 2, 0.0), (cx + sx / 2, cy + sy / 2, h)
            if free(lo, hi, clear_m):
                w.add_box(lo, hi, float(rng.uniform(0.2, 0.9)))
                placed += 1
    # ceiling lights: small boxes hanging from the ceiling, above head height
    for x in np.arange(3.0, 36.0, 4.5):
        for y in (3.5, 8.5, 13.0):
            w.add_box((x - 0.3, y - 0.3, _STOREY_M - 0.08), (x + 0.3, y + 0.3, _STOREY_M), 0.95)
    return w


def corridor_world(length_m: float = 8000.0, width_m: float = 2.4, height_m: float = 2.6) -> World:
    """A long straight corridor (its ends far beyond LiDAR range), smooth walls, no features: geometry leaves
    motion along x unconstrained."""
    w = World("corridor")
    w.add_plane(0.0, 0.3)
    w.add_plane(height_m, 0.5)
    half = length_m / 2
    w.add_box((-half, width_m / 2, 0.0), (half, width_m / 2 + _WALL_M, height_m), 0.6)
    w.add_box((-half, -width_m / 2 - _WALL_M, 0.0), (half, -width_m / 2, height_m), 0.6)
    return w


def _rounded_rectangle(x0: float, y0: float, x1: float, y1: float, r: float, step: float = 20.0) -> np.ndarray:
    """Waypoints around a rectangle (counter-clockwise) with corners rounded to radius ``r``."""
    pts = []
    corners = [(x1, y0, 0.0), (x1, y1, 0.5 * np.pi), (x0, y1, np.pi), (x0, y0, 1.5 * np.pi)]
    prev = (x0, y0, 1.5 * np.pi)
    for cx, cy, heading in corners:
        px, py, _ = prev
        # straight part from previous corner to this one
        d = np.array([np.cos(heading), np.sin(heading)])
        start = np.array([px, py]) + d * r
        end = np.array([cx, cy]) - d * r
        n = max(1, int(np.linalg.norm(end - start) // step))
        for a in np.linspace(0.0, 1.0, n + 1)[:-1]:
            pts.append(start + a * (end - start))
        centre = np.array([cx, cy]) - d * r + np.array([-d[1], d[0]]) * r
        for ang in np.linspace(-0.5 * np.pi, 0.0, 4)[:-1]:
            a = heading + ang
            pts.append(centre + r * np.array([np.cos(a), np.sin(a)]))
        prev = (cx, cy, heading)
    return np.array(pts)


DRIVE_WAYPOINTS = _rounded_rectangle(0.0, 0.0, 160.0, 100.0, 14.0)


def slalom(path: Path2D, amplitude_m: float, wavelength_m: float, step_m: float = 2.5) -> np.ndarray:
    """Waypoints weaving +-``amplitude_m`` across a closed ``path`` (a whole number of waves per lap)."""
    waves = max(1, int(round(path.length_m / wavelength_m)))
    s = np.arange(0.0, path.length_m, step_m)
    p, t = path.derivs(s, 0), path.derivs(s, 1)
    n = np.column_stack([-t[:, 1], t[:, 0]]) / np.linalg.norm(t, axis=1)[:, None]
    return p + n * (amplitude_m * np.sin(2.0 * np.pi * waves * s / path.length_m))[:, None]


def town_world(path_xy: np.ndarray, seed: int = 11) -> World:
    """Ground, blocks of buildings on both sides of a road loop, poles and parked cars by the kerb."""
    w = World("town")
    w.add_plane(0.0, 0.25)
    rng = np.random.default_rng(seed)

    def clear(lo, hi, margin):
        probe = World("probe")
        probe.add_box(lo, hi)
        return footprint_clearance(probe, path_xy).min() > margin

    # buildings along the loop, outside and inside, set back from the road
    for x in np.arange(-40.0, 200.0, 14.0):
        for y in np.arange(-40.0, 140.0, 14.0):
            sx, sy = rng.uniform(8.0, 13.0), rng.uniform(8.0, 13.0)
            cx, cy = x + rng.uniform(-1.5, 1.5), y + rng.uniform(-1.5, 1.5)
            lo, hi = (cx - sx / 2, cy - sy / 2, 0.0), (cx + sx / 2, cy + sy / 2, rng.uniform(5.0, 22.0))
            if clear(lo, hi, 9.0) and not clear(lo, hi, 30.0) and rng.random() < 0.8:
                w.add_box(lo, hi, float(rng.uniform(0.3, 0.8)))
    # poles and parked cars along the road sides
    dense = Path2D(path_xy, closed=True)
    for s in np.arange(0.0, dense.length_m, 17.0):
        p, t = dense.derivs(np.array([s]), 0)[0], dense.derivs(np.array([s]), 1)[0]
        t = t / np.linalg.norm(t)
        n = np.array([-t[1], t[0]])
        for side in (-1.0, 1.0):
            q = p + side * n * rng.uniform(5.5, 6.5)
            if footprint_clearance_cyl(path_xy, q, 0.15) > 4.0:
                w.add_cylinder(q[0], q[1], 0.15, 0.0, rng.uniform(4.0, 7.0), 0.8)
        if rng.random() < 0.5:
            side = 1.0 if rng.random() < 0.5 else -1.0
            q = p + side * n * 3.8
            yaw = np.arctan2(t[1], t[0])
            along = abs(np.cos(yaw)) > abs(np.sin(yaw))
            hx, hy = (2.2, 0.9) if along else (0.9, 2.2)
            lo, hi = (q[0] - hx, q[1] - hy, 0.0), (q[0] + hx, q[1] + hy, 1.5)
            if clear(lo, hi, 2.2):
                w.add_box(lo, hi, float(rng.uniform(0.4, 0.9)))
    return w


def footprint_clearance_cyl(path_xy: np.ndarray, centre: np.ndarray, radius: float) -> float:
    return float(np.min(np.linalg.norm(path_xy - centre, axis=1)) - radius)


def _dense(path: Path2D, step_m: float = 0.05) -> np.ndarray:
    return path.derivs(np.arange(0.0, path.length_m, step_m), 0)


def _start_times(start: str, ramp_s: float = 1.5, fade_s: float = 1.5) -> tuple[float, float, float]:
    """(Progress.t_rest_s, Trajectory.t_rest_s, Scenario.rest_s): 1.5 s at rest, or (moving) the speed ramp,
    the progress wobble's fade-in (2 ramps long) and the sway fade-in all over by t = 0."""
    if start == "still":
        return STILL_REST_S, STILL_REST_S, STILL_REST_S
    if start == "moving":
        return -3.0 * ramp_s, -fade_s, 0.0
    if start == "accelerating":  # mid-ramp at t = 0: half the speed, the ramp's largest acceleration
        return -0.5 * ramp_s, -fade_s, 0.0
    raise KeyError(start)


def build_scenario(name: str, beams: int | None = None, columns: int | None = None, start: str = "still",
                   tilt_scale: float = 1.0, stops: tuple[tuple[float, float], ...] = (),
                   hills: tuple[float, float] | None = None) -> Scenario:
    """The scenario ``name`` (one of SCENARIOS) with a LiDAR of ``beams`` x ``columns``, starting ``start``
    (still, moving or accelerating), its roll and pitch sway scaled by ``tilt_scale``, standing still at
    ``stops`` ((at_s, seconds) pairs, checked and in time order: see :mod:`.stops`), over ``hills``
    ((amplitude_m, wavelength_m), checked: see :mod:`.terrain`; the world's ground stays flat)."""
    sc = _scenario(name, beams, columns, start)
    if tilt_scale != 1.0 and sc.trajectory is not None:
        traj = sc.trajectory
        traj.roll, traj.pitch = (replace(sig, amps=tuple(tilt_scale * a for a in sig.amps))
                                 for sig in (traj.roll, traj.pitch))
    if hills is not None:
        sc.trajectory.terrain = Hills(*(float(v) for v in hills))
    if stops:
        sc.trajectory = StoppedTrajectory(sc.trajectory, tuple(stops))
    return sc


def _scenario(name: str, beams: int | None, columns: int | None, start: str) -> Scenario:
    p_rest, t_rest, rest = _start_times(start)
    if name in ("handheld", "planar"):
        hh, pl = Path2D(HANDHELD_WAYPOINTS), Path2D(PLANAR_WAYPOINTS)
        world = office_world([_dense(hh, 0.1), _dense(pl, 0.1)])
    if name == "handheld":
        traj = Trajectory(
            hh, Progress(1.2, t_rest_s=p_rest, wobble=Sines((0.15, 0.05), (0.13, 0.31), (0.0, 1.0))), z0_m=1.35,
            z_wobble=Sines((0.03,), (1.8,), (0.0,)),
            yaw_offset=Sines((0.5, 0.08), (0.95, 2.1), (0.0, 0.7)),
            pitch=Sines((0.08, 0.03), (0.45, 1.8), (0.3, 0.0)), roll=Sines((0.06, 0.02), (0.9, 1.7), (1.0, 2.0)),
            t_rest_s=t_rest,
        )
        return Scenario(
            name, "person walking indoors through rooms and doorways with fast yaw sweeps; 16-beam spinning LiDAR",
            world, traj, _pose((0.02, -0.03, 0.5 * np.pi), (0.04, -0.02, 0.03)), _pose((0, 0, 0), (0.0, 0.0, 0.10)),
            LidarSpec(beams=beams or 16, columns=columns or 1024, max_range_m=100.0), None, clearance_m=0.3,
            rest_s=rest, gps_antenna_m=(0.0, 0.0, 0.25),
        )
    if name == "planar":
        traj = Trajectory(pl, Progress(0.7, t_rest_s=p_rest, ramp_s=1.5, wobble=Sines((0.1,), (0.1,), (0.0,))),
                          t_rest_s=t_rest)
        return Scenario(
            name, "differential-drive robot in an office: 2D LaserScan, wheel encoders, IMU", world, traj,
            _pose((0.0, 0.0, 0.5 * np.pi), (0.05, 0.02, 0.15)), _pose((0, 0, 0), (0.15, 0.0, 0.30)),
            LaserSpec(beams=columns or 720), WheelSpec(radius_m=0.08, baseline_m=0.42), clearance_m=0.3,
            body_z_m=(0.0, 0.5), rest_s=rest, gps_antenna_m=(-0.1, 0.0, 0.45),
        )
    if name == "corridor":
        xs = np.arange(-60.0, 3950.0, 2.5)  # over an hour of driving before the path ends
        path = Path2D(np.column_stack([xs, 0.4 * np.sin(2 * np.pi * xs / 12.5)]), closed=False)
        traj = Trajectory(path, Progress(1.0, t_rest_s=p_rest, s0_m=30.0, wobble=Sines((0.2,), (0.08,), (0.0,))),
                          t_rest_s=t_rest)
        return Scenario(
            name, "robot in a long featureless corridor: geometry does not constrain motion along it",
            corridor_world(), traj, _pose((0.0, 0.02, 0.5 * np.pi), (0.1, 0.05, 0.25)), _pose((0, 0, 0), (0.2, 0.0, 0.5)),
            LidarSpec(beams=beams or 16, columns=columns or 1024, max_range_m=100.0), WheelSpec(radius_m=0.1, baseline_m=0.5),
            clearance_m=0.3, body_z_m=(0.0, 0.8), rest_s=rest, gps_antenna_m=(0.0, 0.0, 0.6),
        )
    if name == "drive":
        path = Path2D(DRIVE_WAYPOINTS)
        world = town_world(_dense(path, 0.5))
        # moving: cruising at 7.5 m/s from 56 m into the first straight (curvature < 0.0015/m for the next
        # 30 m: yaw rate < 0.01 rad/s); speed wobble (6.2..8.9 m/s) and sway fade in from t = 0
        wobble = Sines((6.0,), (0.05,), (0.0,))
        p_rest, fade, s0 = 1.5, 1.5, 0.0
        if start == "moving":
            wobble, p_rest, fade, s0 = Sines((4.2,), (0.05,), (-0.94,)), -3.0, 3.0, 56.0 - 7.5 * 1.5
        elif start == "accelerating":  # driving off on the same straight: 3.75 m/s and 3.75 m/s^2 at t = 0
            wobble, p_rest, fade, s0 = Sines(), -1.5, 3.0, 56.0 - 7.5 * 0.28125
        traj = Trajectory(
            path, Progress(7.5, t_rest_s=p_rest, ramp_s=3.0, wobble=wobble, s0_m=s0), z0_m=0.0,
            z_wobble=Sines((0.015,), (1.3,), (0.0,)), pitch=Sines((0.012, 0.004), (0.2, 1.1), (0.0, 0.5)),
            roll=Sines((0.015, 0.004), (0.15, 0.9), (1.0, 0.0)), fade_in_s=fade, t_rest_s=max(t_rest, 0.0),
        )
        return Scenario(
            name, "car driving a loop through a town of buildings, poles and parked cars at 5-10 m/s",
            world, traj, _pose((0.01, 0.02, -0.5 * np.pi), (0.8, 0.1, 0.6)), _pose((0, 0, 0), (1.2, 0.0, 1.9)),
            LidarSpec(beams=beams or 32, columns=columns or 1024, max_range_m=120.0),
            WheelSpec(radius_m=0.32, baseline_m=1.6), clearance_m=1.1, body_z_m=(0.0, 1.6), rest_s=rest,
            gps_antenna_m=(-0.5, 0.0, 1.55),
        )
    if name == "rover":
        # a wheeled robot on the town's roads, weaving +-1.5 m (parked cars keep 2.2 m from the road's
        # centre), over uneven ground: +-2-3 deg of roll and pitch and 5 cm of heave at terrain frequencies
        road = Path2D(DRIVE_WAYPOINTS)
        world = town_world(_dense(road, 0.5))
        traj = Trajectory(
            Path2D(slalom(road, 1.5, 30.0)), Progress(1.5, t_rest_s=p_rest, s0_m=100.0, wobble=Sines((0.4,), (0.07,), (0.0,))),
            z0_m=0.0, z_wobble=Sines((0.05, 0.01), (0.19, 0.9), (0.0, 0.4)),
            pitch=Sines((0.03, 0.012), (0.21, 0.83), (0.0, 1.3)), roll=Sines((0.035, 0.01), (0.17, 0.71), (0.6, 0.0)),
            t_rest_s=t_rest,
        )
        return Scenario(
            name, "wheeled ground robot weaving along a town's roads over uneven ground: 16-beam LiDAR, wheels, IMU",
            world, traj, _pose((0.0, 0.0, 0.0), (0.1, 0.0, 0.3)), _pose((0, 0, 0), (0.2, 0.0, 0.7)),
            LidarSpec(beams=beams or 16, columns=columns or 1024, max_range_m=100.0),
            WheelSpec(radius_m=0.15, baseline_m=0.55), clearance_m=0.35, body_z_m=(0.0, 0.8), rest_s=rest,
            gps_antenna_m=(-0.2, 0.0, 0.8),
        )
    if name == "drone":
        # a multicopter over the town's roads: climbing and sinking between 1.5 and 10.5 m, banking +-6-8 deg,
        # its yaw swinging +-35 deg off the direction of travel (it flies sideways too)
        road = Path2D(DRIVE_WAYPOINTS)
        world = town_world(_dense(road, 0.5))
        traj = Trajectory(
            road, Progress(4.0, t_rest_s=p_rest, ramp_s=2.0, s0_m=100.0, wobble=Sines((1.5,), (0.06,), (0.0,))),
            z0_m=6.0, z_wobble=Sines((3.0, 1.5), (0.025, 0.08), (0.0, 1.0)),
            yaw_offset=Sines((0.6,), (0.04,), (0.0,)), pitch=Sines((0.1, 0.02), (0.1, 0.9), (0.4, 0.0)),
            roll=Sines((0.12, 0.02), (0.13, 1.1), (1.2, 0.3)), fade_in_s=2.0, t_rest_s=t_rest,
        )
        return Scenario(
            name, "multicopter flying over a town's roads, climbing and sinking between 1.5 and 10.5 m: 16-beam LiDAR, IMU",
            world, traj, _pose((0.0, 0.0, 0.0), (0.02, 0.0, 0.05)), _pose((0, 0, 0), (0.0, 0.0, 0.15)),
            LidarSpec(beams=beams or 16, columns=columns or 1024, max_range_m=100.0), None, clearance_m=1.0,
            body_z_m=(0.0, 12.0), rest_s=rest, gps_antenna_m=(0.0, 0.0, 0.2),
        )
    if name == "static":
        world = World("table")
        world.add_plane(0.0, 0.3)
        traj = Trajectory(Path2D(np.array([(0.0, 0.0), (10.0, 0.0)]), closed=False), Progress(0.0), z0_m=0.8)
        return Scenario(
            name, "an IMU at rest on a table for hours: white noise and bias random walks only (no LiDAR, no wheels)",
            world, traj, _pose((0.01, -0.02, 0.0), (0.0, 0.0, 0.05)), None, None, None, clearance_m=0.0,
            body_z_m=(0.0, 0.0), rest_s=float("inf"),
        )
    raise KeyError(name)

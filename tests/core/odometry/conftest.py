"""Small constructed inputs for the odometry's steps: a room of surfaces, scans of it from known poses, an
``OdomState`` to run steps on."""

import numpy as np
import pytest

from lio_cli.config.odom import OdomConfig
from lio_cli.core.imu import NavState
from lio_cli.core.odometry.state import OdomState, Settings
from lio_cli.model.calibration import Extrinsics
from lio_cli.model.records import ImuBatch, PointCloud, TimeConvention

SCAN_NS = 100_000_000  # a 10 Hz LiDAR
IMU_PERIOD_NS = 5_000_000  # a 200 Hz IMU
G = 9.81


def _room(rng: np.random.Generator, n: int = 6000) -> np.ndarray:
    """Points on the inside of a 20 x 16 x 4 m room (floor, ceiling, walls) with two pillars: every direction
    constrained."""
    pts = []
    for axis, value, (lo0, hi0), (lo1, hi1) in (
            (2, -1.0, (-10, 10), (-8, 8)), (2, 3.0, (-10, 10), (-8, 8)),
            (0, -10.0, (-8, 8), (-1, 3)), (0, 10.0, (-8, 8), (-1, 3)),
            (1, -8.0, (-10, 10), (-1, 3)), (1, 8.0, (-10, 10), (-1, 3))):
        uv = rng.uniform((lo0, lo1), (hi0, hi1), size=(n // 6, 2))
        p = np.insert(uv, axis, value, axis=1)
        pts.append(p)
    for cx, cy in ((3.0, 2.0), (-4.0, -3.0)):  # square pillars 1 m wide
        t = rng.uniform(-0.5, 0.5, size=(400, 1))
        z = rng.uniform(-1, 3, size=(400, 1))
        for dx, dy in ((0.5, None), (-0.5, None), (None, 0.5), (None, -0.5)):
            x = np.full_like(t, cx + dx) if dx is not None else cx + t
            y = np.full_like(t, cy + dy) if dy is not None else cy + t
            pts.append(np.hstack([x, y, z]))
    return np.vstack(pts)


@pytest.fixture
def room():
    return _room(np.random.default_rng(7))


@pytest.fixture
def make_scan(room):
    """``make_scan(T_world_base, t_end_ns)``: the room seen from a pose (T_base_lidar = I), points stamped over the
    scan's 0.1 s (the platform still during it)."""

    def make(T_world_base: np.ndarray, t_end_ns: int, points_world: np.ndarray | None = None) -> PointCloud:
        pw = room if points_world is None else points_world
        T_inv = np.linalg.inv(T_world_base)
        pts = pw @ T_inv[:3, :3].T + T_inv[:3, 3]
        stamps = np.linspace(t_end_ns - SCAN_NS, t_end_ns, len(pts)).astype(np.int64)
        return PointCloud(t_end_ns - SCAN_NS, "lidar", pts, stamps, TimeConvention("stamps", "t", 1.0))

    return make


@pytest.fixture
def make_state():
    """``make_state(use_imu=False, planar=False, **config)``: an ``OdomState`` as ``LioOdometry`` starts it."""

    def make(use_imu: bool = False, planar: bool = False, **config) -> OdomState:
        cfg = OdomConfig(**config)
        settings = Settings(cfg, use_imu, planar, False, (None, None), imu_prior=use_imu and cfg.prior == "imu",
                            deskew=cfg.resolved_deskew())
        return OdomState(settings, Extrinsics(np.eye(4), np.eye(4)))

    return make


@pytest.fixture
def still_imu():
    """``still_imu(t0_ns, t1_ns)``: samples of an IMU at rest, level (accel +g up), every 5 ms."""

    def make(t0_ns: int, t1_ns: int) -> ImuBatch:
        stamps = np.arange(t0_ns, t1_ns + 1, IMU_PERIOD_NS, dtype=np.int64)
        accel = np.tile([0.0, 0.0, G], (len(stamps), 1))
        return ImuBatch("imu", stamps, np.zeros((len(stamps), 3)), accel)

    return make


@pytest.fixture
def still_state():
    """``still_state(t_ns)``: an IMU state at rest at the origin at ``t_ns``."""

    def make(t_ns: int) -> NavState:
        return NavState(t_ns, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))

    return make

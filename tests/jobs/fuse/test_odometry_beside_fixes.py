"""Odometry stamped microseconds after the GPS fixes (a LiDAR and a receiver on one clock, both at whole tenths
of a second): each gave the factor graph its own keyframe, an IMU factor over microseconds between them so stiff
that LM stopped at its iteration limit far from the minimum (the matrix's 45 s rover: ATE 0.0355 m, 0.0051 with
the stamps equal; this 30 s one 0.0364 and 0.0057). Such stamps now share a keyframe (``keyframes.MERGE_NS``)."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.config.fuse import FuseConfig
from lio_cli.core.fuse.graph import keyframes
from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.io.files.trajectory import format_tum, read_tum
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.model.trajectory import Trajectory
from lio_cli.simulation.run import simulate


@pytest.fixture(scope="module")
def rover(tmp_path_factory):
    d = tmp_path_factory.mktemp("odom_fixes")
    log = d / "rover.mcap"
    # the matrix's rover moving on bad wheels (3 % large, slip bursts) beside a consumer receiver
    simulate("rover", log, duration_s=30.0, seed=7, lidar=False, start="moving", gps=True, gps_model="consumer",
             wheel_errors=False, wheel_radius_scale=[1.03, 1.03], wheel_slip_bursts=3, gps_invalid_fraction=0.02)
    return log


def _odometry(log, path, after_ns: int):
    """Ground truth at 10 Hz with 1 cm of noise, each pose ``after_ns`` after a whole tenth (the fixes' stamps)."""
    t, P = read_tum(log.with_suffix(".gt.tum"))
    keep = (t - t[0]) % 100_000_000 == 0
    s, O = t[keep][1:-1], P[keep][1:-1].copy()
    O[:, :3, 3] += np.random.default_rng(0).normal(0.0, 0.01, (len(s), 3))
    path.write_text(format_tum(s + after_ns, O))
    return path


def _ate(log, traj) -> float:
    t, P = read_tum(log.with_suffix(".gt.tum"))
    ref, est = Trajectory(t, P, "gt"), Trajectory(traj.stamps_ns, traj.poses, "est")
    return evaluate(ref, est, EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


def test_odometry_microseconds_after_the_fixes_solves_as_on_them(rover, tmp_path):
    runs = {}
    for after_ns in (0, 2_339, 20_000):
        cfg = FuseConfig(input={"odom_file": str(_odometry(rover, tmp_path / f"o{after_ns}.tum", after_ns))})
        runs[after_ns] = run_fuse(FuseJob(rover, cfg))
    base = _ate(rover, runs[0].trajectory)
    assert base < 0.02
    for after_ns in (2_339, 20_000):
        sm = runs[after_ns].metrics["core"]["smoother"]
        assert sm["kind"] == "factor_graph" and sm["iterations"] < 20
        assert _ate(rover, runs[after_ns].trajectory) < 1.2 * base


class _Stamps:
    def __init__(self, *ns: int):
        self.stamps_ns = np.array(ns, np.int64)

    def __len__(self) -> int:
        return len(self.stamps_ns)


def test_measurement_stamps_closer_than_the_merge_share_a_keyframe():
    from types import SimpleNamespace

    t0 = 1_000_000_000
    gps = _Stamps(t0 + 200_000_000, t0 + 400_000_000)
    odom = _Stamps(t0 + 200_002_339, t0 + 300_000_000, t0 + 400_060_000)
    prep = SimpleNamespace(t0_ns=t0, t1_ns=t0 + 500_000_000, odom=odom, gps=gps)
    kt = keyframes.keyframe_stamps(prep)
    assert t0 + 200_002_339 not in kt and t0 + 400_060_000 in kt  # 2.3 us folded in, 60 us kept
    assert np.diff(kt).min() >= keyframes.MERGE_NS
    k = keyframes.attach(kt, odom.stamps_ns)
    assert kt[k[0]] == t0 + 200_000_000 and kt[k[1]] == t0 + 300_000_000 and kt[k[2]] == t0 + 400_060_000
    # a stamp just after the last keyframe (merged into it) is that keyframe's
    assert keyframes.attach(kt, np.array([kt[-1] + 10_000]))[0] == len(kt) - 1

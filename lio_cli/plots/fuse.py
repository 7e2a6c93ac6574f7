"""Plots of a fuse run (matplotlib, Agg): the sources and the fused trajectory seen from above, and speed and
yaw rate over time (fused against the wheels and the gyro).

The sources are drawn in the fused world: odometry poses carried there by the fused pose at their first
common instant, GPS fixes shifted by their mean offset from the fused positions at their stamps, and the
wheels dead-reckoned in 2D from the fused start (forward speed, lateral speed where measured, yaw rate from
the gyro when there is one, else the wheels').
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..geometry import interpolate_poses, inv_pose, yaw_of
from ..model.trajectory import Trajectory
from .style import COLORS, pyplot, save_tight, stride

PLOT_FILES = ("fuse_top_view.png", "fuse_speed_yaw_rate.png")  # what ``write_plots`` writes, in order


class FusedRun(Protocol):
    """What the plots read of a fuse run (a ``jobs.fuse.FuseRun``)."""

    trajectory: Trajectory  # T_world_base
    velocities_mps: np.ndarray | None  # (N,3) world frame
    config: Any  # its estimator and smooth
    sources: Any  # its ``inputs``: the wheel, imu, odom and gps series that were fused





def _interp(stamps_ns: np.ndarray, values: np.ndarray, query_ns: np.ndarray) -> np.ndarray:
    t0 = stamps_ns[0]
    return np.column_stack([np.interp((query_ns - t0) * 1e-9, (stamps_ns - t0) * 1e-9, values[:, k])
                            for k in range(values.shape[1])])


def _sorted(stamps: np.ndarray, *arrays):
    o = np.argsort(stamps, kind="stable")
    return (stamps[o], *(a[o] for a in arrays))


def wheel_dead_reckoning(run: FusedRun) -> tuple[np.ndarray, str] | None:
    """((M,2) x, y, label) of the wheels integrated alone in 2D from the fused start at the wheel stamps: their
    own yaw rate, or the gyro's where the wheels carry none."""
    w, imu = run.sources.inputs.wheel, run.sources.inputs.imu
    tr = run.trajectory
    if w is None or len(w) < 2 or len(tr) == 0:
        return None
    st, v, yr = _sorted(w.stamps_ns, w.velocity_mps, w.yaw_rate_radps)
    keep = np.concatenate([[True], np.diff(st) > 0]) & np.isfinite(v[:, 0])
    st, v, yr = st[keep], v[keep], yr[keep]
    if len(st) < 2:
        return None
    label = "wheels dead-reckoned"
    if np.any(np.isfinite(yr)) or imu is None or len(imu) < 2:
        rate = np.nan_to_num(yr)
    else:
        ist, g = _sorted(imu.stamps_ns, imu.gyro_radps @ imu.T_base_imu[:3, :3].T)
        rate = _interp(ist, g[:, 2:3], st)[:, 0]
        label += " (yaw rate from the gyro)"
    dt = np.diff(st) * 1e-9
    yaw0 = float(yaw_of(tr.poses[0, :3, :3]))
    yaw = yaw0 + np.concatenate([[0.0], np.cumsum(rate[:-1] * dt)])
    vx, vy = v[:, 0], np.nan_to_num(v[:, 1])
    step = np.column_stack([vx * np.cos(yaw) - vy * np.sin(yaw), vx * np.sin(yaw) + vy * np.cos(yaw)])[:-1] * dt[:, None]
    return tr.poses[0, :2, 3] + np.vstack([[0.0, 0.0], np.cumsum(step, axis=0)]), label


def _odom_in_world(run: FusedRun) -> np.ndarray | None:
    od, tr = run.sources.inputs.odom, run.trajectory
    if od is None or len(od) == 0 or len(tr) < 2:
        return None
    st, T = _sorted(od.stamps_ns, od.poses)
    ok = (st >= tr.stamps_ns[0]) & (st <= tr.stamps_ns[-1]) & (np.abs(np.linalg.det(T[:, :3, :3]) - 1) < 1e-3)
    if not np.any(ok):
        return None
    st, T = st[ok], T[ok]
    T_w = interpolate_poses(tr.stamps_ns, tr.poses, st[:1])[0]
    return (T_w @ inv_pose(T[0]) @ T)[:, :2, 3]


def _gps_in_world(run: FusedRun) -> np.ndarray | None:
    g, tr = run.sources.inputs.gps, run.trajectory
    if g is None or len(g) == 0 or len(tr) < 2:
        return None
    inside = (g.stamps_ns >= tr.stamps_ns[0]) & (g.stamps_ns <= tr.stamps_ns[-1])
    if not np.any(inside):
        return None
    fused = _interp(tr.stamps_ns, tr.poses[:, :3, 3], g.stamps_ns[inside])
    offset = np.mean(g.position_enu_m[inside] - fused, axis=0)
    return (g.position_enu_m - offset)[:, :2]


def plot_top_view(run: FusedRun, path: Path, force: bool = False) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 7))
    try:
        gps = _gps_in_world(run)
        if gps is not None:
            ax.plot(gps[:, 0], gps[:, 1], "o", color="black", ms=3, alpha=0.5, label="GPS fixes")
        wheels = wheel_dead_reckoning(run)
        if wheels is not None:
            dr, label = wheels
            s = slice(None, None, stride(len(dr)))
            ax.plot(dr[s, 0], dr[s, 1], color=COLORS[2], lw=1.2, ls="--", label=label)
        od = _odom_in_world(run)
        if od is not None:
            s = slice(None, None, stride(len(od)))
            ax.plot(od[s, 0], od[s, 1], color=COLORS[3], lw=1.2, ls="-.", label="odometry input")
        p = run.trajectory.positions
        s = slice(None, None, stride(len(p)))
        c = run.config
        ax.plot(p[s, 0], p[s, 1], color=COLORS[0], lw=1.8,
                label=f"fused ({c.estimator}{' + smoother' if c.smooth else ''})")
        if len(p):
            ax.plot(p[0, 0], p[0, 1], "o", color="black", ms=8, label="start")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title("Top view: sources and fused trajectory")
        ax.legend(loc="best")
        return save_tight(fig, path, force)
    finally:
        plt.close(fig)


def _fused_rates(run: FusedRun) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_s, speed m/s, yaw rate rad/s) of the fused trajectory."""
    tr = run.trajectory
    t = (tr.stamps_ns - tr.stamps_ns[0]) * 1e-9
    if run.velocities_mps is not None:
        speed = np.linalg.norm(run.velocities_mps, axis=1)
    else:
        speed = np.linalg.norm(np.gradient(tr.positions, t, axis=0), axis=1) if len(t) > 1 else np.zeros(len(t))
    yaw = np.unwrap(yaw_of(tr.poses[:, :3, :3]))
    rate = np.gradient(yaw, t) if len(t) > 1 else np.zeros(len(t))
    return t, speed, rate


def plot_speed_yaw_rate(run: FusedRun, path: Path, force: bool = False) -> Path:
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    try:
        tr = run.trajectory
        t0 = tr.stamps_ns[0] if len(tr) else 0
        w, imu = run.sources.inputs.wheel, run.sources.inputs.imu
        if w is not None and len(w):
            st, v, yr = _sorted(w.stamps_ns, w.velocity_mps, w.yaw_rate_radps)
            s = slice(None, None, stride(len(st)))
            ts = (st[s] - t0) * 1e-9
            a1.plot(ts, np.hypot(v[s, 0], np.nan_to_num(v[s, 1])), color=COLORS[2], lw=1.0, label="wheels")
            if np.any(np.isfinite(yr)):
                a2.plot(ts, yr[s], color=COLORS[2], lw=1.0, label="wheels")
        if imu is not None and len(imu):
            st, g = _sorted(imu.stamps_ns, imu.gyro_radps @ imu.T_base_imu[:3, :3].T)
            s = slice(None, None, stride(len(st)))
            a2.plot((st[s] - t0) * 1e-9, g[s, 2], color=COLORS[1], lw=0.8, alpha=0.7, label="gyro z (base)")
        if len(tr):
            t, speed, rate = _fused_rates(run)
            s = slice(None, None, stride(len(t)))
            a1.plot(t[s], speed[s], color=COLORS[0], lw=1.5, label="fused")
            a2.plot(t[s], rate[s], color=COLORS[0], lw=1.5, label="fused")
        a1.set_ylabel("speed [m/s]")
        a2.set_ylabel("yaw rate [rad/s]")
        a2.set_xlabel("time since the first pose [s]")
        a1.set_title("Speed and yaw rate")
        for a in (a1, a2):
            a.legend(loc="best")
        return save_tight(fig, path, force)
    finally:
        plt.close(fig)


def write_plots(run: FusedRun, folder: Path, force: bool = False) -> list[Path]:
    """The ``PLOT_FILES`` of ``run`` in ``folder``."""
    return [plot_top_view(run, folder / PLOT_FILES[0], force), plot_speed_yaw_rate(run, folder / PLOT_FILES[1], force)]


__all__ = ["PLOT_FILES", "FusedRun", "plot_speed_yaw_rate", "plot_top_view", "wheel_dead_reckoning", "write_plots"]

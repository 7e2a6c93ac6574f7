"""The windows behind the wheel scales (``wheel``): the trajectory's and the wheels' motion over each, far-out
windows found and bad poses bridged, and the generalised least squares over one chain of adjacent windows."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cholesky_banded, solve_banded
from scipy.optimize import least_squares, minimize

from ...geometry import yaw_of
from .common import NS_PER_S, true_runs

OUTLIER_SIGMAS = 4.0


@dataclass(frozen=True, eq=False)
class Chain:
    """The fit over one chain of adjacent windows."""

    x: np.ndarray  # (s_v, s_w, d_w)
    cov: np.ndarray  # 3x3
    win: Windows  # the windows used (bridged ones joined)
    slips: list[tuple[int, int]]  # pose index ranges left out
    skipped: set[int]  # poses skipped by a bridge
    levels: np.ndarray  # the whitener's noise levels


def fit_chain(win: Windows, levels: np.ndarray | None = None) -> Chain:
    """Scales over ``win`` (one chain of adjacent windows): a robust fit, far-out windows cut against the
    scatter, bad poses bridged, then generalised least squares. ``levels``: the noise levels of another chain of
    the same trajectory, reused (else found from the residuals)."""
    sig0 = np.array([0.02, 0.02, np.radians(0.3)])
    fit = least_squares(lambda s: win.resid(s, sig0), np.array([1.0, 1.0, 0.0]), loss="cauchy", f_scale=3.0)
    good = np.ones(len(win.ia), bool)
    # the windows' scatter, once, from all of them (the MAD ignores the slips): re-measured after each cut it would
    # shrink with every cut and trim good windows in turn
    r = win.resid(fit.x, sig0).reshape(-1, 3) * sig0
    scale = np.maximum(1.4826 * np.median(np.abs(r - np.median(r, axis=0)), axis=0), np.array([1e-4, 1e-4, 1e-5]))
    for it in range(4):  # flag far-out windows against that scatter, refit on the rest, repeat until stable
        new_good = ~(np.abs(r - np.median(r[good], axis=0)) > OUTLIER_SIGMAS * scale).any(axis=1)
        if it > 0 and (new_good == good).all():
            break
        good = new_good
        fit = least_squares(lambda s, sc=scale, g=good: win.resid(s, sc).reshape(-1, 3)[g].ravel(), fit.x)
        r = win.resid(fit.x, sig0).reshape(-1, 3) * sig0
    # A far-out window is slip only if the windows around it do not make up for it: one badly registered pose
    # throws both windows that share it out by opposite amounts, so such a pose is bridged (the windows on either
    # side joined into one that skips it, kept when it fits) rather than one window of the two left out.
    win, slips, skipped = _bridge(win, good, fit.x, np.median(r[good], axis=0), OUTLIER_SIGMAS * scale)
    fit = least_squares(lambda s: win.resid(s, scale), fit.x)
    # generalised least squares: consecutive windows share a pose, so their position and heading noise cancel
    # along the path (what makes the whole distance, not each window's, set the speed scale's precision)
    adjacent = win.ib[:-1] == win.ia[1:]
    for _ in range(1 if levels is not None else 2):  # noise levels from the residuals, the scales under them, again
        whiten = _Whitener(win.resid(fit.x, np.ones(3)).reshape(-1, 3), win.T_wb[win.ia, :3, :3], adjacent, levels)
        fit = least_squares(lambda s, wh=whiten: wh(win.resid(s, np.ones(3)).reshape(-1, 3)), fit.x)
    cov = np.linalg.inv(fit.jac.T @ fit.jac + np.eye(3))  # + a unit prior: a factor the motion never shows stays finite
    return Chain(fit.x, cov, win, slips, skipped, whiten.levels)


def relative(T_wb: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """(forward, lateral, yaw) of pose ib in the frame of pose ia: the trajectory's side of each window."""
    R_rel = np.einsum("nji,njk->nik", T_wb[ia, :3, :3], T_wb[ib, :3, :3])
    rel_t = np.einsum("nji,nj->ni", T_wb[ia, :3, :3], T_wb[ib, :3, 3] - T_wb[ia, :3, 3])
    return np.column_stack([rel_t[:, 0], rel_t[:, 1], yaw_of(R_rel)])


class Windows:
    """Windows [ts[ia], ts[ib]] of the trajectory (base poses ``T_wb`` at ``ts``) and the wheels' corrected
    motion over each (``plane``, shared by every set of windows of the same log)."""

    def __init__(self, plane: Plane, ts: np.ndarray, T_wb: np.ndarray, ia: np.ndarray, ib: np.ndarray,
                 cross: float) -> None:
        self.plane, self.ts, self.T_wb, self.cross = plane, ts, T_wb, cross
        self.ia, self.ib = ia, ib
        self.meas = relative(T_wb, ia, ib)
        self.ta, self.tb = plane.seconds(ts[ia]), plane.seconds(ts[ib])

    def with_windows(self, ia: np.ndarray, ib: np.ndarray) -> Windows:
        return Windows(self.plane, self.ts, self.T_wb, ia, ib, self.cross)

    def track(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The wheels' path under the factors ``s`` = (s_v, s_w, d_w)."""
        return self.plane.track(s[0], s[1], s[2], self.cross * s[2] * s[0] / s[1])

    def raw(self, s: np.ndarray, track: tuple | None = None) -> np.ndarray:
        """(n, 3) wheels minus trajectory, yaw wrapped (``track``: ``self.track(s)`` when already at hand)."""
        d = self.plane.relative(self.track(s) if track is None else track, self.ta, self.tb) - self.meas
        d[:, 2] = np.mod(d[:, 2] + np.pi, 2.0 * np.pi) - np.pi
        return d

    def resid(self, s: np.ndarray, sig: np.ndarray) -> np.ndarray:
        return (self.raw(s) / sig).ravel()


def _bridge(win: Windows, good: np.ndarray, x: np.ndarray, centre: np.ndarray,
            limit: np.ndarray) -> tuple[Windows, list[tuple[int, int]], set[int]]:
    """The windows kept, with each run of far-out ones joined to at most one neighbour on each side into a
    single window where that fits (a bad pose skipped); the runs that fit no way are slip: returned as pose
    index ranges, with the poses the joined windows skip."""
    n = len(good)
    track = win.track(x)  # the wheels' path once; each run's candidate windows are read off it
    used = ~good  # windows already in a joined window or left out
    joined: list[tuple[int, int]] = []
    slips: list[tuple[int, int]] = []
    for a, b in true_runs(~good):
        before, after = a > 0 and not used[a - 1], b < n and not used[b]  # a good neighbour free to join
        cands = [(a, b - 1)] + [(a - 1, b - 1)] * before + [(a, b)] * after + [(a - 1, b)] * (before and after)
        lo, hi = np.array(cands).T
        d = np.abs(win.with_windows(win.ia[lo], win.ib[hi]).raw(x, track) - centre) / limit
        # the fewest windows joined, then the best fit
        fits = [(hi[i] - lo[i], float(d[i].max()), i) for i in np.flatnonzero((d <= 1.0).all(axis=1))]
        if not fits:
            slips.append((int(win.ia[a]), int(win.ib[b - 1])))
            continue
        i = min(fits)[2]
        lo, hi = cands[i]
        used[lo:hi + 1] = True
        joined.append((lo, hi))
    single = np.flatnonzero(~used)
    ia = np.concatenate([win.ia[single], [win.ia[lo] for lo, _ in joined]]).astype(np.int64)
    ib = np.concatenate([win.ib[single], [win.ib[hi] for _, hi in joined]]).astype(np.int64)
    order = np.argsort(ia, kind="stable")
    skipped = {int(p) for lo, hi in joined for p in win.ib[lo:hi]}
    return win.with_windows(ia[order], ib[order]), slips, skipped


class Plane:
    """Wheel odometry integrated on the plane, corrected; relative (x, y, yaw) over windows [ta, tb] (s)."""

    def __init__(self, ws: np.ndarray, v: np.ndarray, w: np.ndarray) -> None:
        self.t0 = ws[0]
        self.t = self.seconds(ws)
        dt = np.diff(self.t)
        self.dth = 0.5 * (w[1:] + w[:-1]) * dt  # heading step at unit yaw scale
        self.ds = 0.5 * (v[1:] + v[:-1]) * dt  # distance step at unit speed scale

    def seconds(self, stamps_ns: np.ndarray) -> np.ndarray:
        return (stamps_ns - self.t0) / NS_PER_S

    def track(self, s_v: float, s_w: float, d_w: float = 0.0,
              e_v: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, heading) at the wheel stamps with v = s_v v_wheel + e_v w_wheel and w = s_w w_wheel + d_w v_wheel."""
        dth = s_w * self.dth + d_w * self.ds
        ds = s_v * self.ds + e_v * self.dth
        th = np.concatenate([[0.0], np.cumsum(dth)])
        mid = th[:-1] + 0.5 * dth
        sinc = np.sinc(0.5 * dth / np.pi)  # exact arc over each step
        x = np.concatenate([[0.0], np.cumsum(ds * np.cos(mid) * sinc)])
        y = np.concatenate([[0.0], np.cumsum(ds * np.sin(mid) * sinc)])
        return x, y, th

    def relative(self, track: tuple, ta: np.ndarray, tb: np.ndarray) -> np.ndarray:
        xa, ya, tha = (np.interp(ta, self.t, q) for q in track)
        xb, yb, thb = (np.interp(tb, self.t, q) for q in track)
        c, s = np.cos(tha), np.sin(tha)
        dx, dy = xb - xa, yb - ya
        return np.column_stack([c * dx + s * dy, -s * dx + c * dy, thb - tha])


class _Whitener:
    """Whitens stacked window residuals (n,3) = (forward, lateral, yaw) under per-pose noise that adjacent
    windows share (position sigma_p, heading sigma_h: they cancel along the path) plus white noise per window.
    The four noise levels are the maximum-likelihood ones for the residuals given."""

    def __init__(self, r: np.ndarray, R_start: np.ndarray, adjacent: np.ndarray,
                 levels: np.ndarray | None = None) -> None:
        self.n = len(r)
        self.P = np.einsum("nji,njk->nik", R_start[:-1], R_start[1:])[:, :2, :2]  # frame k -> frame k+1 (plane)
        self.adj = np.flatnonzero(adjacent)
        if levels is None:
            v = np.array([0.5 * (r[:, :2] ** 2).sum(axis=1).mean(), (r[:, 2] ** 2).mean()])
            v = np.maximum(v, 1e-12)
            x0 = np.log(np.concatenate([0.4 * v, 0.2 * v]))  # [sigma_p^2, sigma_h^2, white_xy, white_yaw]
            lo = np.log(np.concatenate([v, v]) * 1e-6)  # a level vanishing would make the whitening blow up
            best = minimize(lambda x: self._nll(np.exp(np.maximum(x, lo)), r), x0, method="Nelder-Mead",
                            options={"xatol": 1e-3, "fatol": 1e-6, "maxiter": 800})
            levels = np.exp(np.maximum(best.x, lo))
        self.levels = levels
        self.L = self._cholesky(levels)

    def _cholesky(self, q: np.ndarray) -> np.ndarray:
        sp2, sh2, wxy, wh = q
        ab = np.zeros((6, 3 * self.n))  # lower band storage: ab[d, j] = S[j + d, j]
        ab[0] = np.tile([2 * sp2 + wxy, 2 * sp2 + wxy, 2 * sh2 + wh], self.n)
        k = self.adj
        j0 = 3 * k
        for di in range(2):  # block (k+1, k): -sigma_p^2 (R_k^T R_k+1)^T in the plane, -sigma_h^2 in yaw
            for dj in range(2):
                ab[3 + di - dj, j0 + dj] = -sp2 * self.P[k, dj, di]
        ab[3, j0 + 2] = -sh2
        return cholesky_banded(ab, lower=True)

    def _nll(self, q: np.ndarray, r: np.ndarray) -> float:
        try:
            L = self._cholesky(q)
        except np.linalg.LinAlgError:
            return 1e300
        z = solve_banded((5, 0), L, r.reshape(-1))
        return float(np.log(L[0]).sum() + 0.5 * z @ z)

    def __call__(self, r: np.ndarray) -> np.ndarray:
        return solve_banded((5, 0), self.L, r.reshape(-1))

"""A PNG of the Allan deviation curves with the fitted lines (returned as bytes; the caller writes it)."""

from __future__ import annotations

import io

import numpy as np

from ..core.calibration.allan import AllanFit, AllanResult


def allan_plot_png(result: AllanResult, title: str = "Allan deviation", dpi: int = 110) -> bytes:
    """Two log-log panels (gyro, accelerometer): the measured deviation per axis, the fitted white-noise (-1/2)
    and random-walk (+1/2) lines, the whole fitted model, and the read-outs at tau = 1 s and 3 s."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.6))
    axes = fig.subplots(1, 2)
    for ax, fit, adev, name, unit in ((axes[0], result.gyro, result.gyro_adev_radps, "gyroscope", "rad/s"),
                                      (axes[1], result.accel, result.accel_adev_mps2, "accelerometer", "m/s^2")):
        _panel(ax, result.taus_s, adev, fit, name, unit)
    fig.suptitle(f"{title} ({result.duration_s / 3600:.2f} h at {result.rate_hz:.0f} Hz)")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _panel(ax, taus: np.ndarray, adev: np.ndarray, fit: AllanFit, name: str, unit: str) -> None:
    colors = ("tab:red", "tab:green", "tab:blue")
    t = np.logspace(np.log10(taus[0]), np.log10(taus[-1]), 200)
    for k, axis in enumerate("xyz"):
        c = colors[k]
        ax.loglog(taus, adev[:, k], "o", ms=2.5, color=c, alpha=0.6, label=f"{axis}")
        N2, cB, K2 = fit.model_avar[k]
        ax.loglog(t, np.sqrt(N2 / t + cB + K2 * t / 3.0), "-", color=c, lw=1.0, alpha=0.8)
        ax.loglog(t, np.sqrt(N2 / t), ":", color=c, lw=0.8)
        if K2 > 0:
            ax.loglog(t, np.sqrt(K2 * t / 3.0), "--", color=c, lw=0.8)
        ax.plot([1.0], [fit.noise_density[k]], "s", color=c, mfc="none")
        ax.plot([3.0], [fit.random_walk[k]], "^", color=c, mfc="none")
    b_note = f"B {fit.bias_instability.mean():.2e} (min/0.664)"
    ax.set_title(f"{name}: N {fit.noise_density_mean:.2e} (slope {np.nanmean(fit.white_slope):+.2f}), "
                 f"K {fit.random_walk_mean:.2e} (slope {np.nanmean(fit.random_walk_slope):+.2f})\n{b_note}",
                 fontsize=9)
    ax.set_xlabel("tau [s]")
    ax.set_ylabel(f"Allan deviation [{unit}]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(title="dots: data, line: fit\n: white  -- walk", fontsize=8, title_fontsize=7, loc="lower left")

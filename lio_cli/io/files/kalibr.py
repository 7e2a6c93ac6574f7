"""Kalibr's ``imu.yaml`` from an Allan-variance result (returned as text; the caller writes it)."""

from __future__ import annotations

from ...core.calibration.allan import AllanResult


def kalibr_imu_yaml(result: AllanResult, rostopic: str = "/imu", update_rate_hz: float | None = None) -> str:
    """Kalibr's imu.yaml: each value the average of the three axes (continuous-time densities, as Kalibr
    wants them; Kalibr's docs suggest inflating them for real sensors, which is left to the user)."""
    rate = result.rate_hz if update_rate_hz is None else float(update_rate_hz)
    g, a = result.gyro, result.accel
    return (
        "#Accelerometers\n"
        f"accelerometer_noise_density: {a.noise_density_mean:.6e}   #Noise density (continuous-time) [m/s^2/sqrt(Hz)]\n"
        f"accelerometer_random_walk:   {a.random_walk_mean:.6e}   #Bias random walk [m/s^3/sqrt(Hz)]\n"
        "\n"
        "#Gyroscopes\n"
        f"gyroscope_noise_density:     {g.noise_density_mean:.6e}   #Noise density (continuous-time) [rad/s/sqrt(Hz)]\n"
        f"gyroscope_random_walk:       {g.random_walk_mean:.6e}   #Bias random walk [rad/s^2/sqrt(Hz)]\n"
        "\n"
        f"rostopic:                    {rostopic}   #the IMU ROS topic\n"
        f"update_rate:                 {rate:.1f}   #Hz (for discretization of the values above)\n"
    )

"""Scan registration: kiss-icp's voxel map and ICP, driven with our own initial guesses.

The only module that imports kiss_icp: its compiled bindings, through the same calls as its Python wrappers
(``kiss_icp.mapping``, ``registration``, ``threshold``, ``voxelization``), which import kiss-icp's pydantic
configuration and with it a tenth of a second of start-up that lio never uses.
"""

from __future__ import annotations

import math

import numpy as np
from kiss_icp.pybind import kiss_icp_pybind as kiss

from ...config.odom import RegistrationConfig

_IMU_PRIOR_ITERATIONS = 20
_KISS_ITERATIONS = 500
_SOURCE_FACTOR = 2.5  # sparser registered points than kiss-icp's 1.5: faster for a little accuracy
_PLANAR_SOURCE_FACTOR = 1.5  # kiss-icp's own default, for 2D scans


def voxel_down_sample(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """kiss-icp's voxelisation: the first point of each voxel, in order."""
    return np.asarray(kiss._voxel_down_sample(kiss._Vector3dVector(points), voxel_size))


class VoxelMap:
    """kiss-icp's voxel hash map (``kiss_icp.mapping.VoxelHashMap``)."""

    def __init__(self, voxel_size: float, max_distance: float, max_points_per_voxel: int) -> None:
        self.native = kiss._VoxelHashMap(voxel_size=voxel_size, max_distance=max_distance,
                                         max_points_per_voxel=max_points_per_voxel)

    def empty(self) -> bool:
        return self.native._empty()

    def update(self, points: np.ndarray, pose: np.ndarray) -> None:
        """Add ``points`` at ``pose``; points farther than the maximum distance from it leave the map."""
        self.native._update(kiss._Vector3dVector(points), pose)

    def point_cloud(self) -> np.ndarray:
        return np.asarray(self.native._point_cloud())


class Icp:
    """kiss-icp's point-to-point ICP with a robust kernel (``kiss_icp.registration.Registration``)."""

    def __init__(self, iterations: int, convergence: float, threads: int) -> None:
        self.native = kiss._Registration(max_num_iterations=iterations, convergence_criterion=convergence,
                                         max_num_threads=threads)

    def align_points_to_map(self, points: np.ndarray, voxel_map: VoxelMap, guess: np.ndarray, max_distance: float,
                            kernel: float) -> np.ndarray:
        return self.native._align_points_to_map(points=kiss._Vector3dVector(points), voxel_map=voxel_map.native,
                                                initial_guess=guess, max_correspondance_distance=max_distance,
                                                kernel=kernel)


class FixedThreshold:
    """kiss-icp's fixed kernel width (its ``adaptive_threshold.fixed_threshold``)."""

    def __init__(self, sigma: float) -> None:
        self.sigma = sigma

    def get_threshold(self) -> float:
        return self.sigma

    def update_model_deviation(self, deviation: np.ndarray) -> None:
        pass


class AdaptiveThreshold:
    """kiss-icp's kernel width from the registrations' deviations from their guesses."""

    def __init__(self, initial_threshold: float, min_motion_th: float, max_range: float) -> None:
        self.native = kiss._AdaptiveThreshold(initial_threshold=initial_threshold, min_motion_th=min_motion_th,
                                              max_range=max_range)

    def get_threshold(self) -> float:
        return self.native._compute_threshold()

    def update_model_deviation(self, deviation: np.ndarray) -> None:
        self.native._update_model_deviation(model_deviation=deviation)


class ScanRegistration:
    """A local voxel map and the registration of de-skewed scans against it.

    ``fixed_correspondence_m``: with a good prior (the IMU prediction is within centimetres) correspondences
    are gated at this distance and ICP stops after few iterations; None keeps kiss-icp's adaptive threshold.
    """

    def __init__(self, rc: RegistrationConfig, voxel_size_m: float, *, imu_prior: bool, planar: bool,
                 fixed_correspondence_m: float | None) -> None:
        self.voxel_size_m = voxel_size_m
        # a dense 3D scan keeps enough structure at 2.5 voxels; a 2D scan's few hundred beams do not
        self.source_factor = rc.source_voxel_factor or (_PLANAR_SOURCE_FACTOR if planar else _SOURCE_FACTOR)
        self.max_source_points = rc.max_source_points
        # a coarse-to-fine ICP where an IMU prediction starts it (never with kiss-icp's own iterations)
        self.coarse_points = rc.coarse_points if imu_prior else None
        self.refine_iterations = rc.refine_iterations
        self.iterations = rc.max_iterations or (_IMU_PRIOR_ITERATIONS if imu_prior else _KISS_ITERATIONS)
        self.convergence, self.threads = rc.convergence, rc.threads
        self.map = VoxelMap(voxel_size_m, rc.max_range_m, rc.max_points_per_voxel)
        self._registration = Icp(self.iterations, rc.convergence, rc.threads)
        # kiss-icp gates correspondences at 3 sigma with a kernel of sigma: a fixed gate g is sigma = g / 3
        self._threshold = (AdaptiveThreshold(rc.initial_threshold_m, rc.min_motion_m, rc.max_range_m)
                           if fixed_correspondence_m is None else FixedThreshold(fixed_correspondence_m / 3.0))
        self._adaptive = AdaptiveThreshold(rc.initial_threshold_m, rc.min_motion_m, rc.max_range_m)
        # without a good prior (start-up window, recovery): kiss-icp's own adaptive gate and iterations
        self._wide_registration = Icp(rc.max_iterations or _KISS_ITERATIONS, rc.convergence, rc.threads)
        self._capped: dict[int, Icp] = {}  # iterations -> registration (where the IMU prediction is leant on)
        self.scans = 0  # scans added to the map

    @property
    def empty(self) -> bool:
        return self.map.empty()

    def downsample(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(points kept for the map, sparser points registered), as kiss-icp's double voxelisation; with
        ``max_source_points``, registered points past it are thinned again with voxels grown by the square root of
        the excess (the points lie on surfaces: their count falls with the voxel's area)."""
        frame = voxel_down_sample(points, self.voxel_size_m * 0.5)
        voxel = self.voxel_size_m * self.source_factor
        source = voxel_down_sample(frame, voxel)
        cap = self.max_source_points
        if cap is not None and len(source) > cap:
            source = voxel_down_sample(frame, voxel * math.sqrt(len(source) / cap))
        return frame, source

    def register(self, source: np.ndarray, guess: np.ndarray, adaptive: bool = False,
                 gate_m: float | None = None, iterations: int | None = None) -> np.ndarray:
        """T_world_base that best aligns ``source`` (base frame) to the map, starting from ``guess``.

        ``adaptive``: the guess may be coarse, so kiss-icp's full iterations are used, with correspondences
        gated at ``gate_m`` or, when None, by kiss-icp's adaptive threshold. ``iterations``: at most this many
        (an IMU prediction good enough to lean on), else the configured maximum.
        """
        if self.map.empty():
            return guess
        if adaptive:
            sigma = self._adaptive.get_threshold() if gate_m is None else gate_m / 3.0
            return self._wide_registration.align_points_to_map(source, self.map, guess, 3.0 * sigma, sigma)
        sigma = self._threshold.get_threshold()
        reg = self._registration if iterations is None else self._capped_registration(iterations)
        coarse, refine = self.coarse_points, self.refine_iterations
        if coarse is not None and len(source) > 2 * coarse and (iterations is None or iterations > refine):
            # ICP costs points x iterations: most iterations on a sparser copy, the last few on every point (a cap
            # of at most refine_iterations, as lio deskew's, already is that few)
            sparse = voxel_down_sample(source, self.voxel_size_m * self.source_factor * math.sqrt(len(source) / coarse))
            guess = reg.align_points_to_map(sparse, self.map, guess, 3.0 * sigma, sigma)
            reg = self._capped_registration(refine)
        return reg.align_points_to_map(source, self.map, guess, 3.0 * sigma, sigma)

    def _capped_registration(self, iterations: int):
        if iterations >= self.iterations:  # a cap never adds iterations
            return self._registration
        reg = self._capped.get(iterations)
        if reg is None:
            reg = self._capped[iterations] = Icp(iterations, self.convergence, self.threads)
        return reg

    def accept(self, correction: np.ndarray | None, frame: np.ndarray, pose: np.ndarray) -> None:
        """Feed the registration's deviation from its guess to the threshold models and add ``frame`` at ``pose``."""
        if correction is not None:
            self._threshold.update_model_deviation(correction)
            self._adaptive.update_model_deviation(correction)
        self.map.update(frame, pose)
        self.scans += 1



def auto_voxel_size(ranges_m: np.ndarray) -> float:
    """Map voxel size from the first scan: ~1% of the far ranges (kiss-icp's rule), within [0.5, 1.0] m."""
    far = float(np.percentile(ranges_m, 95)) if len(ranges_m) else 100.0
    return float(np.clip(far / 40.0, 0.5, 1.0))

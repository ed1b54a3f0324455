"""Capture: what each probe sees, as a radiance cube on the bake grid (pure numpy + Embree, no ``pxr``).

:func:`capture_probes` renders (or loads, for probes with a captured image) one (6, N, N, 3) float32 cube per
probe of a :class:`bakery.capture.scene.CaptureScene`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from bakery.capture.image import load_captured_cube
from bakery.capture.render import CaptureStats, ProbeRenderer, capture_probe_cube, probe_seed
from bakery.capture.scene import CaptureScene, Dome, Light, Material, Mesh, ProbeSpec
from bakery.sphere.cubemap import cube_texel_directions, sample_cube_bilinear

__all__ = [
    "CaptureReport",
    "CaptureScene",
    "CaptureStats",
    "Dome",
    "Light",
    "Material",
    "Mesh",
    "ProbeRenderer",
    "ProbeSpec",
    "capture_probe_cube",
    "capture_probes",
    "probe_seed",
    "to_face_size",
]


def to_face_size(cube: np.ndarray, face_size: int) -> np.ndarray:
    """Resample a capture (6, M, M, 3) to the bake grid (6, N, N, 3): box average when M = k·N, else bilinear."""
    m = cube.shape[1]
    if m == face_size:
        return cube
    if m % face_size == 0:
        k = m // face_size
        return cube.reshape(6, face_size, k, face_size, k, 3).mean(axis=(2, 4)).astype(np.float32)
    directions = cube_texel_directions(face_size).reshape(-1, 3)
    return sample_cube_bilinear(cube, directions).reshape(6, face_size, face_size, 3).astype(np.float32)


@dataclass(frozen=True)
class CaptureReport:
    """Totals of one capture run: rays traced, seconds spent rendering, probes rendered and loaded from images."""

    rays: int
    seconds: float
    rendered: int
    loaded: int

    @property
    def rays_per_second(self) -> float:
        return self.rays / self.seconds if self.seconds > 0 else 0.0


def capture_probes(
    scene: CaptureScene, face_size: int, samples: int = 4, bounces: int = 1, base_seed: int = 0
) -> tuple[np.ndarray, CaptureReport]:
    """Radiance cubes (P, 6, N, N, 3) float32 of every probe of ``scene`` (in ``scene.probes`` order), each captured
    at its own resolution (``ProbeSpec.resolution``, 0 = N) and resampled to N (:func:`to_face_size`)."""
    cubes = np.zeros((len(scene.probes), 6, face_size, face_size, 3), dtype=np.float32)
    renderer: ProbeRenderer | None = None
    rays, seconds, rendered, loaded = 0, 0.0, 0, 0
    for i, probe in enumerate(scene.probes):
        n = probe.resolution or face_size
        if probe.image:
            cubes[i] = to_face_size(load_captured_cube(probe.image, np.asarray(probe.rotation), n), face_size)
            loaded += 1
            continue
        if renderer is None:
            start = time.perf_counter()
            renderer = ProbeRenderer(scene, samples=samples, bounces=bounces, base_seed=base_seed)
            seconds += time.perf_counter() - start
        cube, stats = renderer.render(np.asarray(probe.position), n, probe.name)
        cubes[i] = to_face_size(cube, face_size)
        rays += stats.rays
        seconds += stats.seconds
        rendered += 1
    return cubes, CaptureReport(rays=rays, seconds=seconds, rendered=rendered, loaded=loaded)

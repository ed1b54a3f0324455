"""Capture: what each probe sees, as a radiance cube on the bake grid (pure numpy + Embree, no ``pxr``).

:func:`capture_probes` renders (or loads, for probes with a captured image) one (6, N, N, 3) float32 cube per
probe of a :class:`bakery.capture.scene.CaptureScene`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from bakery.capture.image import load_captured_cube
from bakery.capture.render import DEFAULT_BOUNCES, CaptureStats, ProbeRenderer, capture_probe_cube, probe_seed
from bakery.capture.scene import CaptureScene, Dome, Light, Material, Mesh, ProbeSpec, Texture
from bakery.sphere.cubemap import resample_cube

__all__ = [
    "CaptureReport",
    "CaptureScene",
    "CaptureStats",
    "DEFAULT_BOUNCES",
    "Dome",
    "Light",
    "Material",
    "Mesh",
    "ProbeRenderer",
    "ProbeSpec",
    "Texture",
    "capture_probe_cube",
    "capture_probes",
    "probe_seed",
]


@dataclass(frozen=True)
class CaptureReport:
    """Totals of one capture run: rays traced, seconds spent rendering, probes rendered and loaded from images, and
    each rendered probe's achieved SH noise and share of camera rays that see back faces (NaN for loaded probes;
    :class:`~bakery.capture.render.CaptureStats`)."""

    rays: int
    seconds: float
    rendered: int
    loaded: int
    sh_noise: tuple[float, ...] = ()
    backface_fraction: tuple[float, ...] = ()

    @property
    def rays_per_second(self) -> float:
        return self.rays / self.seconds if self.seconds > 0 else 0.0


def capture_probes(
    scene: CaptureScene, face_size: int, samples: int = 4, bounces: int = DEFAULT_BOUNCES, base_seed: int = 0,
    target_noise: float = 0.0,
) -> tuple[np.ndarray, CaptureReport]:
    """Radiance cubes (P, 6, N, N, 3) float32 of every probe of ``scene`` (in ``scene.probes`` order), each captured
    at its own resolution (``ProbeSpec.resolution``, 0 = N) and resampled to N, flux-preserving
    (:func:`bakery.sphere.cubemap.resample_cube`)."""
    cubes = np.zeros((len(scene.probes), 6, face_size, face_size, 3), dtype=np.float32)
    renderer: ProbeRenderer | None = None
    rays, seconds, rendered, loaded = 0, 0.0, 0, 0
    noise: list[float] = []
    backfaces: list[float] = []
    for i, probe in enumerate(scene.probes):
        n = probe.resolution or face_size
        if probe.image:
            cubes[i] = resample_cube(load_captured_cube(probe.image, np.asarray(probe.rotation), n), face_size)
            loaded += 1
            noise.append(float("nan"))
            backfaces.append(float("nan"))
            continue
        if renderer is None:
            start = time.perf_counter()
            renderer = ProbeRenderer(scene, samples=samples, bounces=bounces, base_seed=base_seed,
                                     target_noise=target_noise)
            seconds += time.perf_counter() - start
        cube, stats = renderer.render(np.asarray(probe.position), n, probe.name, probe.relocate)
        cubes[i] = resample_cube(cube, face_size)
        rays += stats.rays
        seconds += stats.seconds
        rendered += 1
        noise.append(stats.sh_noise)
        backfaces.append(stats.backface_fraction)
    return cubes, CaptureReport(rays=rays, seconds=seconds, rendered=rendered, loaded=loaded, sh_noise=tuple(noise),
                                backface_fraction=tuple(backfaces))

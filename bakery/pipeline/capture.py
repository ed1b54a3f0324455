"""Capture functions, by kind: turn a :class:`CaptureSpec` into a radiance cube on the bake grid.

Registered kinds:
    ``environment``  a distant probe: the environment image at ``source`` resampled to the bake grid; the full
                     resolution image is kept as the probe's reference quadrature.
    ``scene``        a probe in a USD scene, rendered by :mod:`bakery.capture` (registered by
                     :mod:`bakery.scene_bake` when the USD part is installed).

Workers cache what does not change between probes (a decoded image, a scene's ray-tracing structures) per process.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np

from bakery.environment.io import read_environment
from bakery.environment.resample import environment_samples, resample_to_cube
from bakery.environment.sanitize import SanitizeReport
from bakery.sphere.grid import SphericalSamples

#: kind → f(spec, face_size, probe) → (cube (6, N, N, 3), reference samples or None, sanitize report or None
#: [, statistics {name: number} summed into the batch timings])
CAPTURES: dict[str, Callable] = {}

#: Modules that register capture kinds, imported on first use (a worker process may not have imported them).
_PROVIDERS = {"scene": "bakery.scene_bake"}


def capture_function(kind: str) -> Callable:
    """The capture function of ``kind``, importing its provider module on first use."""
    if kind not in CAPTURES and kind in _PROVIDERS:
        import importlib

        importlib.import_module(_PROVIDERS[kind])
    try:
        return CAPTURES[kind]
    except KeyError:
        raise KeyError(f"unknown capture kind {kind!r}; known: {', '.join(sorted(set(CAPTURES) | set(_PROVIDERS)))}") from None


def register_capture(kind: str) -> Callable[[Callable], Callable]:
    def decorate(function: Callable) -> Callable:
        CAPTURES[kind] = function
        return function

    return decorate


@lru_cache(maxsize=4)
def _environment(path: str, layout: str | None, face_size: int) -> tuple[np.ndarray, SphericalSamples, SanitizeReport]:
    image, report = read_environment(path, layout=layout)
    return resample_to_cube(image, face_size), environment_samples(image), report


@register_capture("environment")
def capture_environment(spec, face_size: int, probe):  # noqa: ANN001, ARG001
    cube, samples, report = _environment(spec.source, spec.param("layout"), face_size)
    return cube, samples, report

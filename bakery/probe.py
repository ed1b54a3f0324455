"""Probes and batches of captured radiance: what encoders consume.

A probe's capture is a cube map on the bake grid (:mod:`bakery.sphere.cubemap`, conventions in
:mod:`bakery.conventions`): (6, N, N, 3) float32 linear radiance seen from the probe's position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from bakery.sh.projection import SHProjector
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.grid import SphericalSamples

if TYPE_CHECKING:
    from bakery.irradiance.reference import BinnedQuadrature

PROBE_KINDS = ("irradiance", "reflection")


@dataclass(frozen=True)
class Probe:
    """Identity and placement of one probe (plain data; USD prims become these).

    Attributes:
        name: unique, stable identity (a prim path, or ``/environment`` for a distant probe).
        kinds: which encodings families it needs, subset of :data:`PROBE_KINDS`.
        position: (3,) bake-frame position in metres (zeros for a distant probe).
        settings: per-probe overrides (e.g. ``{"encodings": [...]}``), plain JSON-able data.
    """

    name: str
    kinds: tuple[str, ...] = PROBE_KINDS
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    settings: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        from bakery.errors import ConfigError

        if not self.kinds or any(k not in PROBE_KINDS for k in self.kinds):
            raise ConfigError(f"{self.name}: probe kinds must be a non-empty subset of {PROBE_KINDS}, got {self.kinds}")
        try:
            finite = len(self.position) == 3 and all(math.isfinite(float(x)) for x in self.position)
        except (TypeError, ValueError):
            finite = False
        if not finite:
            raise ConfigError(f"{self.name}: probe position must be three finite numbers, got {self.position}")


_GRID_CACHE: dict[tuple[int, int], SHProjector] = {}


def cube_projector(face_size: int, max_band: int) -> SHProjector:
    """SH projector of the bake cube grid, cached per (face size, band limit)."""
    key = (face_size, max_band)
    if key not in _GRID_CACHE:
        _GRID_CACHE[key] = SHProjector(
            cube_texel_directions(face_size).reshape(-1, 3), cube_texel_solid_angles(face_size).reshape(-1), max_band
        )
    return _GRID_CACHE[key]


class ProbeBatch:
    """Captured radiance of P probes on one bake grid, with derived quantities cached.

    Args:
        cubes: (P, 6, N, N, 3) float32 radiance.
        reference_samples: optional per-probe full-resolution quadratures (the source image of a distant probe,
            as :class:`~bakery.sphere.grid.SphericalSamples` or binned,
            :class:`~bakery.irradiance.reference.BinnedQuadrature`), used by the reference diagnostics; ``None``
            means the cube itself is the reference.
    """

    def __init__(self, cubes: np.ndarray,
                 reference_samples: list[SphericalSamples | BinnedQuadrature] | None = None) -> None:
        cubes = np.asarray(cubes, dtype=np.float32)
        if cubes.ndim != 5 or cubes.shape[1] != 6 or cubes.shape[2] != cubes.shape[3] or cubes.shape[4] != 3:
            raise ValueError(f"cubes must be (P, 6, N, N, 3), got {cubes.shape}")
        self.cubes = cubes
        self.reference_samples = reference_samples
        self._sh: dict[int, np.ndarray] = {}

    @property
    def count(self) -> int:
        return int(self.cubes.shape[0])

    @property
    def face_size(self) -> int:
        return int(self.cubes.shape[2])

    def texels(self) -> np.ndarray:
        """Radiance (P, 6·N·N, 3) flattened in cube texel order."""
        return self.cubes.reshape(self.count, -1, 3)

    def radiance_sh(self, max_band: int = 2) -> np.ndarray:
        """Radiance SH (P, (L+1)², 3), projected with one matrix product for the batch (cached)."""
        if max_band not in self._sh:
            self._sh[max_band] = cube_projector(self.face_size, max_band).project(self.texels())
        return self._sh[max_band]


class RadianceSHBatch(ProbeBatch):
    """Probes known only by their radiance SH bands 0–2 (P, 9, 3), e.g. dilated ones
    (:mod:`bakery.pipeline.dilate`). Every irradiance encoding is a function of these alone and encodes such a
    batch exactly as the batch of the captures they were projected from (conformance suite); anything that needs
    the radiance itself (the reflection fits, the reference quadrature) raises ``ValueError``."""

    def __init__(self, radiance_sh: np.ndarray) -> None:  # noqa: D107 - no cubes (ProbeBatch.__init__ not called)
        radiance_sh = np.asarray(radiance_sh, dtype=np.float64)
        if radiance_sh.ndim != 3 or radiance_sh.shape[1:] != (9, 3):
            raise ValueError(f"radiance SH must be (P, 9, 3), got {radiance_sh.shape}")
        self._sh = {2: radiance_sh}
        self.reference_samples = None

    @property
    def cubes(self) -> np.ndarray:  # type: ignore[override]
        raise ValueError("these probes are known by their radiance SH bands 0-2 alone; no cube to read")

    @property
    def count(self) -> int:
        return int(self._sh[2].shape[0])

    @property
    def face_size(self) -> int:
        raise ValueError("these probes are known by their radiance SH bands 0-2 alone; they have no face size")

    def radiance_sh(self, max_band: int = 2) -> np.ndarray:
        if max_band > 2:
            raise ValueError(f"radiance SH up to band {max_band} requested; these probes hold bands 0-2")
        return self._sh[2][:, : (max_band + 1) ** 2]

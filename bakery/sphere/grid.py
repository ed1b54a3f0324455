"""Flattened spherical samples: what every integrator and projector consumes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SphericalSamples:
    """A quadrature of the sphere with radiance: texel centres, their exact solid angles and values.

    Attributes:
        directions: (T, 3) unit vectors in the bake frame.
        solid_angles: (T,) steradians; sums to 4π for a full-sphere grid.
        radiance: (T, C) scene-linear radiance.
    """

    directions: np.ndarray
    solid_angles: np.ndarray
    radiance: np.ndarray

    def __post_init__(self) -> None:
        t = self.directions.shape[0]
        if self.directions.shape != (t, 3) or self.solid_angles.shape != (t,) or self.radiance.shape[0] != t:
            raise ValueError(
                f"inconsistent sample shapes: directions {self.directions.shape}, "
                f"solid_angles {self.solid_angles.shape}, radiance {self.radiance.shape}"
            )

    @property
    def count(self) -> int:
        return int(self.directions.shape[0])

    def flux(self) -> np.ndarray:
        """∫ L dω per channel: (C,)."""
        return self.solid_angles @ self.radiance

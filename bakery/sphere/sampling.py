"""Local frames on the sphere.

References
    [Duff17] T. Duff et al., "Building an Orthonormal Basis, Revisited", JCGT 6(1), 2017 (Listing 3: branchless,
        no cancellation near n = ±z).
"""

from __future__ import annotations

import numpy as np


def orthonormal_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent t and bitangent b (..., 3) with (t, b, n) a right-handed orthonormal frame of unit n (..., 3)
    ([Duff17])."""
    n = np.asarray(n, dtype=np.float64)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    s = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (s + z)
    b = x * y * a
    t = np.stack([1.0 + s * x * x * a, s * b, -s * x], axis=-1)
    bt = np.stack([b, s + y * y * a, -y], axis=-1)
    return t, bt

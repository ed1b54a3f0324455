"""Plain spherical-harmonic irradiance encodings: radiance SH of bands 0–1 or 0–2, float32.

Defines
    class   name   what
    ------  -----  -----------------------------------------------------------------------------------------
    SH2     sh2    linear SH, 4 radiance coefficients × RGB (48 bytes)
    SH3     sh3    quadratic SH, 9 radiance coefficients × RGB (108 bytes)

Parameters
    none (``Params = NoParams``).

Both store *radiance* coefficients (index l(l+1)+m, RGB last, :mod:`bakery.conventions`); irradiance is
reconstructed with the cosine-lobe factors π, 2π/3, π/4
(:func:`bakery.irradiance.sh_irradiance.evaluate_sh_irradiance`).

References
    [ZH3] T. Roughton, P.-P. Sloan, A. Silvennoinen, M. Iwanicki, P. Shirley, "ZH3: Quadratic Zonal Harmonics",
          Proc. ACM Comput. Graph. Interact. Tech. 7(1), 2024 (seed 001): linear and quadratic SH are its baselines.
"""

from __future__ import annotations

import numpy as np

from bakery.encodings.base import Encoding, FieldSpec, NoParams
from bakery.encodings.registry import register
from bakery.irradiance.sh_irradiance import evaluate_sh_irradiance
from bakery.probe import ProbeBatch

#: The stored linear band (shared with the ZH3 encodings of :mod:`bakery.encodings.zh3`).
LINEAR_SH = FieldSpec("radiance_sh", (4, 3), "float32", "radiance SH bands 0-1, index l*(l+1)+m, RGB last")
QUADRATIC_SH = FieldSpec("radiance_sh", (9, 3), "float32", "radiance SH bands 0-2, index l*(l+1)+m, RGB last")


class SH2(Encoding):
    """Linear SH: 4 radiance coefficients per channel (48 bytes as float32)."""

    name = "sh2"
    kind = "irradiance"
    description = "linear SH (bands 0-1) of radiance"
    Params = NoParams
    max_band = 1
    radiance_sh_field = "radiance_sh"

    def field_specs(self):
        return (LINEAR_SH,)

    def encode(self, batch: ProbeBatch):
        return {"radiance_sh": batch.radiance_sh(2)[:, :4].astype(np.float32)}

    def evaluate_irradiance(self, fields, normals):
        return evaluate_sh_irradiance(fields["radiance_sh"].astype(np.float64), normals)


class SH3(Encoding):
    """Quadratic SH: 9 radiance coefficients per channel (108 bytes as float32)."""

    name = "sh3"
    kind = "irradiance"
    description = "quadratic SH (bands 0-2) of radiance"
    Params = NoParams
    max_band = 2
    radiance_sh_field = "radiance_sh"

    def field_specs(self):
        return (QUADRATIC_SH,)

    def encode(self, batch: ProbeBatch):
        return {"radiance_sh": batch.radiance_sh(2).astype(np.float32)}

    def evaluate_irradiance(self, fields, normals):
        return evaluate_sh_irradiance(fields["radiance_sh"].astype(np.float64), normals)


register(SH2, SH3)

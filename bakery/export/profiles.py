"""Roughness ↔ mip-level profiles: how each consumer picks the mip of a prefiltered cube for a given roughness.

Every consumer maps roughness to mip level differently, so an export re-prefilters the chain at the GGX α each
consumer will assume for each level (``alphas``), at standard halving face sizes N_i = max(1, N >> i)
(:func:`level_sizes`). r is perceptual roughness, α = r² (``bakery.conventions``), M the number of mip levels of
the exported chain, N the face size of level 0.

========  =====================================================  ===========================================
profile   consumer's mapping (lod from roughness)                 α of level i (inverse)
========  =====================================================  ===========================================
gltf      glTF Sample Viewer / glTF-IBL-Sampler:                 r_i = i/(M−1), α = r_i²  (bakery's splitsum)
          lod = r·(M−1)
filament  Filament (``surface_light_indirect.fs``):              r_i = 1 − √(1 − i/(M−1)), α = r_i²
          lod = (M−1)·r(2−r)
three     three.js r187 PMREM (``roughnessToMip``, "matches       as filament
          Filament"): lod = ENVMAP_MAX_LOD·r(2−r)
babylon   Babylon.js PBR (``getLodFromAlphaG``):                 α_i = min(1, 2^((i − o)/s) / N), s = (M−1)/log2 N
          lod = s·log2(N·α) + o, α = r²; the glTF loader's       (EXT_lights_image_based loader), o = 0
          EXT_lights_image_based sets s = (M−1)/log2 N, o = 0
========  =====================================================  ===========================================

Level 0 of ``gltf``/``filament``/``three`` is α = 0 (the capture itself); Babylon's level 0 is α = 1/N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Profile:
    name: str
    consumer: str
    mapping: str  # the consumer's roughness → lod formula, as text (written into each exported file)

    def alphas(self, levels: int, face_size: int) -> np.ndarray:
        """GGX α of every level of an M = ``levels`` chain whose level 0 has faces of ``face_size``."""
        m = max(levels - 1, 1)
        i = np.arange(levels, dtype=np.float64)
        if self.name == "gltf":
            r = i / m
        elif self.name in ("filament", "three"):
            r = 1.0 - np.sqrt(np.clip(1.0 - i / m, 0.0, 1.0))
        elif self.name == "babylon":
            scale = (levels - 1) / max(math.log2(face_size), 1e-9) if face_size > 1 else 1.0
            alpha = np.minimum(1.0, np.exp2(i / max(scale, 1e-9)) / face_size)
            return alpha
        else:  # pragma: no cover - PROFILES lists every name
            raise KeyError(self.name)
        return r * r

    def lod(self, alpha: np.ndarray, levels: int, face_size: int) -> np.ndarray:
        """The consumer's continuous mip level for GGX α (the forward mapping), clamped to [0, M − 1]."""
        a = np.clip(np.asarray(alpha, dtype=np.float64), 0.0, 1.0)
        m = levels - 1
        r = np.sqrt(a)
        if self.name == "gltf":
            x = r * m
        elif self.name in ("filament", "three"):
            x = m * r * (2.0 - r)
        else:
            scale = m / max(math.log2(face_size), 1e-9)
            x = scale * np.log2(np.maximum(face_size * a, 1e-30))
        return np.clip(x, 0.0, m)

    def describe(self, levels: int, face_size: int) -> dict:
        """The profile as written into every exported file's metadata."""
        return {"name": self.name, "consumer": self.consumer, "mapping": self.mapping, "levels": levels,
                "face_size": face_size,
                "level_alphas": [float(a) for a in self.alphas(levels, face_size)]}


PROFILES: dict[str, Profile] = {
    p.name: p for p in (
        Profile("gltf", "glTF Sample Viewer / glTF-IBL-Sampler", "lod = r * (levels - 1), alpha = r^2"),
        Profile("filament", "Filament", "lod = (levels - 1) * r * (2 - r), alpha = r^2"),
        Profile("three", "three.js r187 (PMREM roughnessToMip)", "lod = (levels - 1) * r * (2 - r), alpha = r^2"),
        Profile("babylon", "Babylon.js (EXT_lights_image_based loader)",
                "lod = s * log2(N * alpha) + o, s = (levels - 1) / log2(N), o = 0"),
    )
}


def get_profile(name: str) -> Profile:
    from bakery.errors import ConfigError

    if name not in PROFILES:
        raise ConfigError(f"unknown profile {name!r}; profiles: {', '.join(PROFILES)}")
    return PROFILES[name]


def level_sizes(face_size: int, levels: int) -> tuple[int, ...]:
    """Standard halving mip sizes max(1, N >> i) (what KTX2 and EXT_lights_image_based can express)."""
    return tuple(max(1, face_size >> i) for i in range(levels))


def full_chain_levels(face_size: int) -> int:
    """Levels of a full mip chain down to 1×1: ⌊log2 N⌋ + 1."""
    return int(math.floor(math.log2(max(face_size, 1)))) + 1

"""What an export reads from a store: the capture of each reflection probe, its re-prefiltered chain at a profile's
α per level, and the radiance SH (bands 0–2) of each probe's irradiance.

The capture kept in the store
    A reflection encoding whose field ``level0`` is its α = 0 level (settings ``level_alphas[0] == 0``) stores the
    capture itself at the chain's face size (``schemas/store-reflection.md``; an encoding with a per-probe
    ``first_level`` keeps it only where that is 0 or ``keep_capture`` is set: :func:`captures`). It is float16:
    values carry a relative rounding error ≤ 2⁻¹¹ ≈ 4.9e-4 and radiance above 65504 was clamped at bake time
    (the bake warns). Re-prefiltering therefore matches a float32 capture within 4.9e-4 relative wherever the
    capture stayed below 65504; the exported float16 textures round the same way, so the export adds no visible
    error. Encodings are found by this capability, never by name.

Re-prefiltering
    :func:`prefilter_for_profile` runs bakery's own chain prefilter (:func:`bakery.reflection.splitsum.prefilter_chain`:
    SH-domain levels where the kernel is band-limited, cached sparse operators of the exact kernel for sharp levels,
    α = 0 a copy) with the profile's α per level and standard halving sizes. :func:`profile_chains` streams: it
    checks the whole selection first (every probe keeps a capture, the sizes fit), then yields one probe at a time,
    prefiltering :data:`EXPORT_CHUNK` probes per batched call (:func:`~bakery.reflection.splitsum.prefilter_batch`:
    a probe's chain does not depend on its batch), so an export holds one chunk of captures and chains at a time.

Irradiance SH
    :func:`radiance_sh` fits radiance SH f (9, 3) in bakery's basis to the store's own ``evaluate_irradiance`` of an
    irradiance encoding with ``max_band ≤ 2`` (least squares on 256 Fibonacci normals of E = Σ A_l f_lm Y_lm; exact
    for every such encoding, including ZH3 variants, because their irradiance lies in the span of bands 0–2), or,
    for a probe without one, projects its kept capture onto bands 0–2 (exact texel solid angles).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bakery.encodings import ENCODINGS
from bakery.errors import InputError
from bakery.reflection.blocks import PROBE_BLOCK, probe_blocks
from bakery.reflection.splitsum import (
    SplitSumSettings,
    prefilter_batch,
    prefilter_chain,
)
from bakery.sh.basis import evaluate_sh_basis, sh_bands
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.fibonacci import fibonacci_directions

#: Cosine-lobe band factors A_l (bakery.conventions: irradiance = Σ A_l f_lm Y_lm).
COSINE_BANDS = np.array([np.pi, 2.0 * np.pi / 3.0, np.pi / 4.0])


@dataclass(frozen=True)
class ProfileChainSettings(SplitSumSettings):
    """A prefiltered chain with explicit per-level α and face sizes (the export profiles')."""

    alphas: tuple[float, ...] = ()
    sizes: tuple[int, ...] = ()

    def level_alphas(self) -> np.ndarray:
        return np.asarray(self.alphas, dtype=np.float64)

    def level_sizes(self) -> tuple[int, ...]:
        return tuple(self.sizes)


def _profile_settings(face_size: int, alphas: np.ndarray, sizes: tuple[int, ...]) -> ProfileChainSettings:
    return ProfileChainSettings(face_size=face_size, n_levels=len(alphas), alphas=tuple(float(a) for a in alphas),
                                sizes=tuple(int(s) for s in sizes))


def prefilter_for_profile(capture: np.ndarray, alphas: np.ndarray, sizes: tuple[int, ...]) -> list[np.ndarray]:
    """Re-prefiltered chain [(6, N_i, N_i, 3) float32] of one capture (6, N, N, 3) at GGX ``alphas``."""
    capture = np.asarray(capture, dtype=np.float32)
    return prefilter_chain(capture, _profile_settings(capture.shape[1], alphas, sizes))


def capture_encodings() -> list[str]:
    """Registered reflection encodings that keep the capture as their α = 0 ``level0`` (by default settings)."""
    names = []
    for name, cls in ENCODINGS.items():
        if cls.kind != "reflection":
            continue
        try:
            enc = cls()
        except Exception:  # noqa: BLE001 - an encoding that cannot be built with defaults keeps nothing we know
            continue
        alphas = enc.settings.get("level_alphas")
        if any(f.name == "level0" for f in enc.field_specs()) and alphas and float(alphas[0]) == 0.0:
            names.append(name)
    return names


def stored_capture_encoding(store) -> str | None:  # noqa: ANN001 - bakery.api.ProbeStore
    """The store's encoding that keeps the capture (None if it has none)."""
    for name, info in store.encodings.items():
        alphas = info.settings.get("level_alphas")
        if info.kind == "reflection" and alphas and float(alphas[0]) == 0.0 and "level0" in store.fields(name):
            return name
    return None


def require_capture_encoding(store) -> str:  # noqa: ANN001
    name = stored_capture_encoding(store)
    if name is None:
        candidates = ", ".join(capture_encodings()) or "none registered"
        raise InputError(f"{store.path}: no stored reflection encoding keeps the capture (an α = 0 level0), which a "
                         f"cube-map export re-prefilters; bake the reflection probes with one of: {candidates}")
    return name


def captures(store, encoding: str, probes: list[str]) -> dict[str, np.ndarray]:  # noqa: ANN001
    """{probe: capture (6, N, N, 3) float32} from the α = 0 level of ``encoding``.

    The encoding says which probes keep it (:meth:`~bakery.encodings.Encoding.captures_kept`; e.g. the hybrid
    only where ``first_level`` is 0 or with ``keep_capture``); any other requested probe is an
    :class:`InputError` (nothing is exported: its cube maps would be black)."""
    fields = store.fields(encoding)
    rows = _kept_capture_rows(store, encoding, probes)
    return {p: np.asarray(fields["level0"][r], dtype=np.float32) for p, r in zip(probes, rows, strict=True)}


def _kept_capture_rows(store, encoding: str, probes: list[str]) -> np.ndarray:  # noqa: ANN001
    """The rows of ``probes`` in ``encoding``; an :class:`InputError` if one keeps no capture (:func:`captures`)."""
    fields = store.fields(encoding)
    rows = store.rows(encoding, probes)
    kept = ENCODINGS[encoding].captures_kept(fields, store.encodings[encoding].settings)
    missing = [p for p, r in zip(probes, rows, strict=True) if not kept[r]]
    if missing:
        raise InputError(f"{store.path}: {len(missing)} reflection probe(s) of {encoding} keep no capture (their "
                         f"materials need no level sharper than first_level > 0, so level0 was not stored), e.g. "
                         f"{missing[0]}; re-bake with the encoding setting {encoding}.keep_capture = true to "
                         f"export them, or export only the others (--probes)")
    return rows


def irradiance_encoding(store, probe: str) -> str | None:  # noqa: ANN001
    """The stored irradiance encoding (max_band ≤ 2) with the most bands that has ``probe`` (registry order on
    ties)."""
    table = getattr(store, "_export_irradiance", None)
    if table is None:
        table, bands = {}, {}
        for name, info in store.encodings.items():
            cls = ENCODINGS.get(name)
            if info.kind != "irradiance" or cls is None or cls.max_band is None or cls.max_band > 2:
                continue
            for i in store.fields(name)["probe_index"]:
                probe_name = store.probe_names[int(i)]
                if cls.max_band > bands.get(probe_name, -1):
                    table[probe_name], bands[probe_name] = name, cls.max_band
        store._export_irradiance = table
    return table.get(probe)


_FIT_NORMALS = fibonacci_directions(256)


def radiance_sh_from_irradiance(store, encoding: str, probes: list[str]) -> np.ndarray:  # noqa: ANN001
    """Radiance SH (P, 9, 3) whose irradiance equals ``encoding``'s (least squares, exact for band ≤ 2)."""
    e = store.evaluate_irradiance(encoding, _FIT_NORMALS, probes=probes)  # (P, M, 3)
    design = evaluate_sh_basis(_FIT_NORMALS, 2) * COSINE_BANDS[sh_bands(2)][None, :]  # (M, 9)
    solution, *_ = np.linalg.lstsq(design, e.transpose(1, 0, 2).reshape(len(_FIT_NORMALS), -1), rcond=None)
    return solution.reshape(9, len(probes), 3).transpose(1, 0, 2)


def radiance_sh_from_capture(capture: np.ndarray) -> np.ndarray:
    """Radiance SH (9, 3) of a capture (6, N, N, 3): Σ_texels L Y Ω."""
    n = capture.shape[1]
    basis = evaluate_sh_basis(cube_texel_directions(n).reshape(-1, 3), 2)
    weights = cube_texel_solid_angles(n).reshape(-1, 1)
    return (basis * weights).T @ np.asarray(capture, dtype=np.float64).reshape(-1, 3)


def radiance_sh(store, probe: str, capture: np.ndarray | None = None) -> tuple[np.ndarray, str]:  # noqa: ANN001
    """(radiance SH (9, 3), where it came from) for one probe."""
    encoding = irradiance_encoding(store, probe)
    if encoding is not None:
        return radiance_sh_from_irradiance(store, encoding, [probe])[0], f"irradiance encoding {encoding}"
    if capture is not None:
        return radiance_sh_from_capture(capture), "projection of the kept capture"
    raise InputError(f"{store.path}: probe {probe} has no irradiance encoding with bands <= 2 (and no kept capture)")


def irradiance_probes(store) -> list[str]:  # noqa: ANN001
    """Probes that have an irradiance encoding with max_band ≤ 2."""
    return [p for p in store.probe_names if irradiance_encoding(store, p) is not None]


def reflection_probes(store, probes: list[str], encoding: str) -> list[str]:  # noqa: ANN001
    """The selected probes that ``encoding`` (the kept capture) has, in store order."""
    index = {store.probe_names[int(i)] for i in store.fields(encoding)["probe_index"]}
    return [p for p in probes if p in index]


#: Probes prefiltered per batched call while an export streams (bounded memory: one chunk of captures and chains;
#: the same bound as a bake's chains).
EXPORT_CHUNK = PROBE_BLOCK


@dataclass
class ProfileChains:
    """The re-prefiltered chains of an export's reflection probes at a profile's α, streamed (module doc
    "Re-prefiltering"). Iterating yields (probe, chain [(6, N_i, N_i, 3) float32], capture (6, N, N, 3) float32)
    in ``probes`` order, computing :data:`EXPORT_CHUNK` probes at a time; ``record`` is the profile record (levels,
    face size, α per level, source) written into each file."""

    store: Any  # bakery.api.ProbeStore
    encoding: str
    probes: list[str]
    rows: np.ndarray
    face_size: int
    alphas: np.ndarray
    sizes: tuple[int, ...]
    record: dict = field(default_factory=dict)

    def __iter__(self) -> Iterator[tuple[str, list[np.ndarray], np.ndarray]]:
        from bakery.sphere.cubemap import resample_cube

        level0 = self.store.fields(self.encoding)["level0"]
        settings = _profile_settings(self.face_size, self.alphas, self.sizes)
        for part in probe_blocks(len(self.probes), EXPORT_CHUNK):
            caps = np.asarray(level0[self.rows[part]], dtype=np.float32)
            if caps.shape[2] != self.face_size:
                caps = np.stack([resample_cube(c, self.face_size) for c in caps]).astype(np.float32)
            levels = prefilter_batch(caps, settings)
            for i, probe in enumerate(self.probes[part]):
                yield probe, [level[i] for level in levels], caps[i]


def profile_chains(store, probes: list[str], profile, levels: int | None, face_size: int | None,  # noqa: ANN001
                   power_of_two: bool = False) -> ProfileChains:
    """The reflection probes among ``probes`` with their chains at ``profile``'s α (:class:`ProfileChains`),
    everything checked before any is prefiltered: an :class:`InputError` if none is a reflection probe with a
    kept capture, one keeps no capture, or ``face_size`` / ``levels`` do not fit the kept capture.

    ``face_size`` must divide the kept capture's N (None: N). ``power_of_two``, for consumers that accept only
    power-of-two cube faces (Babylon.js: "Texture size must be a power of two"): None means the largest power of two
    ≤ N, an explicit ``face_size`` must be a power of two ≤ N, and a size that does not divide N is reached by the
    flux-preserving :func:`~bakery.sphere.cubemap.resample_cube` (an N = 12 bake exports 8² faces)."""
    from bakery.export.profiles import full_chain_levels, level_sizes

    encoding = require_capture_encoding(store)
    selected = reflection_probes(store, probes, encoding)
    if not selected:
        raise InputError(f"{store.path}: none of the selected probes is a reflection probe with a kept capture "
                         f"({encoding})")
    rows = _kept_capture_rows(store, encoding, selected)
    n = int(store.fields(encoding)["level0"].shape[2])
    if face_size is None:
        size = 1 << (n.bit_length() - 1) if power_of_two else n
    else:
        size = int(face_size)
    if power_of_two:
        if size < 1 or size > n or size & (size - 1):
            raise InputError(f"face_size {size} must be a power of two <= the kept capture's face size {n} (this "
                             f"format's consumer loads only power-of-two cube faces)")
    elif size < 1 or size > n or n % size:
        raise InputError(f"face_size {size} must divide the kept capture's face size {n}")
    count = full_chain_levels(size) if levels is None else int(levels)
    if not 1 <= count <= full_chain_levels(size):
        raise InputError(f"levels must be 1..{full_chain_levels(size)} for {size}² faces, got {count}")
    record = {**profile.describe(count, size), "source_encoding": encoding,
              "source_precision": "float16 capture (relative rounding <= 4.9e-4; radiance above 65504 clamped)"}
    return ProfileChains(store, encoding, selected, rows, size, profile.alphas(count, size),
                         level_sizes(size, count), record)

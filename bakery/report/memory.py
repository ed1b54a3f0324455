"""Memory accounting of a probe store against the usual alternatives for the same probes.

Per encoding: bytes per probe (the store's ``bytes_per_probe``: the sum of its per-probe fields, shared tables
excluded) × its probe count. Per probe kind (``irradiance``, ``reflection``): the sum over that kind's encodings.

Shared tables (``/encodings/<name>/shared/*``, e.g. the 64×64×2 float32 ``dfg`` table = 32 768 bytes of every
reflection encoding, ``schemas/store-reflection.md``): not per probe, so not in any per-probe figure or per-kind
total. Listed per encoding (``shared_bytes``: Σ dtype size × element count of its shared datasets) and counted
**once per distinct content** in ``shared_tables`` / ``shared_bytes`` (tables with byte-identical contents —
every reflection encoding's ``dfg`` — are one upload for an engine), and ``total_bytes_with_shared`` = the
per-probe total + that. Encodings with no probe are not counted (nothing of theirs is uploaded).

Uploaded bytes per probe (what an engine uploads): each encoding's :meth:`~bakery.encodings.base.Encoding.upload_bytes`
of its stored fields — ``bytes_per_probe``, except for ``shexp_hybrid`` (``schemas/store-reflection.md``), whose levels
below a probe's ``first_level`` (and the gap levels it skips, ``gap_skipped``) are zero-filled in the fixed layout and
not uploaded: a probe that needs no chain uploads its SH exponential and lights only. Mean, min and max over the
encoding's probes.

Comparisons (computed, not measured on a GPU)
    * SH3 floats: 9 coefficients × 3 channels × 4 bytes = 108 bytes per probe.
    * Split-sum chains ([Kar13]; seed 000 Sec. 3.2) with ``L`` levels, base face size ``N`` and a minimum level
      size ``m`` (paper: 32×32):
          cube:        Σ_i 6 · N_i²,  N_i = max(N >> i, min(m, N))
          octahedral:  Σ_i M_i²,      M_i = max(2N >> i, min(m, 2N))   (one square of side 2N covers the sphere)
      in RGBA16F (8 bytes per texel) and BC6H-equivalent size (16 bytes per 4×4 block = 1 byte per texel; levels
      smaller than a block counted as a full block). Chain parameters come from a stored reflection encoding's
      settings (``face_size``, ``n_levels``, ``min_face_size``) when there is one, else the bake face size with
      the defaults of :class:`bakery.reflection.splitsum.SplitSumSettings`.

References
    [Kar13] Karis, "Real Shading in Unreal Engine 4", SIGGRAPH 2013 course notes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: Bytes per probe of quadratic SH stored as float32 RGB.
SH3_FLOAT_BYTES = 9 * 3 * 4
#: Bytes per texel of RGBA16F and of BC6H (16-byte 4×4 blocks).
RGBA16F_BYTES_PER_TEXEL = 8
BC6H_BYTES_PER_BLOCK = 16


@dataclass(frozen=True)
class ChainSettings:
    face_size: int
    n_levels: int = 6
    min_face_size: int = 32

    def cube_sizes(self) -> list[int]:
        floor = min(self.min_face_size, self.face_size)
        return [max(self.face_size >> i, floor) for i in range(self.n_levels)]

    def octahedral_sizes(self) -> list[int]:
        base = 2 * self.face_size
        floor = min(self.min_face_size, base)
        return [max(base >> i, floor) for i in range(self.n_levels)]


def _bc6h_bytes(side: int) -> int:
    blocks = -(-side // 4)
    return blocks * blocks * BC6H_BYTES_PER_BLOCK


def chain_bytes(chain: ChainSettings) -> dict[str, int]:
    """Bytes per probe of split-sum chains: cube/octahedral × RGBA16F/BC6H (module doc)."""
    cube, octa = chain.cube_sizes(), chain.octahedral_sizes()
    return {
        "cube_rgba16f": sum(6 * s * s * RGBA16F_BYTES_PER_TEXEL for s in cube),
        "cube_bc6h": sum(6 * _bc6h_bytes(s) for s in cube),
        "octahedral_rgba16f": sum(s * s * RGBA16F_BYTES_PER_TEXEL for s in octa),
        "octahedral_bc6h": sum(_bc6h_bytes(s) for s in octa),
    }


def chain_settings_for(store: Any) -> ChainSettings:
    """Chain parameters from a stored reflection encoding's settings, else the bake face size and defaults."""
    default_levels, default_min = 6, 32
    try:
        from bakery.reflection.splitsum import SplitSumSettings

        default_levels, default_min = SplitSumSettings().n_levels, SplitSumSettings().min_face_size
    except ImportError:  # pragma: no cover - reflection package absent
        pass
    face = int(store.attributes.get("bake_face_size", 64))
    for info in store.encodings.values():
        s = info.settings
        if info.kind == "reflection" and "n_levels" in s:
            return ChainSettings(int(s.get("face_size", face)), int(s["n_levels"]),
                                 int(s.get("min_face_size", default_min)))
    return ChainSettings(face, default_levels, default_min)


def upload_bytes(store: Any, name: str) -> np.ndarray:
    """(P_k,) bytes an engine uploads for each probe of encoding ``name``: the encoding's own rule
    (:meth:`bakery.encodings.base.Encoding.upload_bytes`) on its stored fields, or the stored bytes per probe for an
    encoding this bakery cannot read (a newer bakery's)."""
    from bakery.encodings import get_encoding

    info = store.encodings[name]
    if info.probe_count == 0 or store.unsupported_reason(name):
        return np.full(info.probe_count, info.bytes_per_probe, dtype=np.int64)
    return get_encoding(name).from_settings(info.settings).upload_bytes(store.fields(name))


def shared_tables(store: Any) -> list[dict[str, Any]]:
    """Distinct shared tables of the encodings that hold probes (module doc): [{"tables": ["<enc>/shared/<name>",
    …], "dtype", "shape", "bytes"}], one entry per distinct (dtype, shape, content)."""
    from bakery.files import sha256_bytes

    distinct: dict[tuple[str, tuple[int, ...], str], dict[str, Any]] = {}
    for name, info in store.encodings.items():
        if info.probe_count == 0:
            continue
        try:
            tables = store.shared(name)
        except Exception:  # noqa: BLE001 - an encoding this bakery cannot read: no shared tables to show
            continue
        for key in sorted(tables):
            array = np.ascontiguousarray(tables[key])
            digest = sha256_bytes(array.tobytes())
            entry = distinct.setdefault((array.dtype.str, tuple(array.shape), digest), {
                "tables": [], "dtype": array.dtype.name, "shape": list(array.shape), "bytes": int(array.nbytes)})
            entry["tables"].append(f"{name}/shared/{key}")
    return list(distinct.values())


def memory_summary(store: Any) -> dict[str, Any]:
    """Memory table of a store (see module doc): per encoding, per kind, and the comparison sizes."""
    kinds = [k.split(",") for k in store.probe_kinds]
    probes_of_kind = {kind: sum(kind in k for k in kinds) for kind in ("irradiance", "reflection")}
    encodings = {}
    per_kind: dict[str, int] = {}
    for name, info in store.encodings.items():
        total = info.bytes_per_probe * info.probe_count
        uploads = upload_bytes(store, name)
        try:
            shared = sum(int(np.asarray(a).nbytes) for a in store.shared(name).values())
        except Exception:  # noqa: BLE001 - unreadable (newer) encoding
            shared = None
        encodings[name] = {"kind": info.kind, "bytes_per_probe": info.bytes_per_probe,
                           "probes": info.probe_count, "total_bytes": total, "shared_bytes": shared,
                           "upload_bytes_per_probe": ({"mean": float(uploads.mean()), "min": int(uploads.min()),
                                                       "max": int(uploads.max())} if uploads.size else None),
                           "upload_total_bytes": int(uploads.sum())}
        per_kind[info.kind] = per_kind.get(info.kind, 0) + total
    chain = chain_settings_for(store)
    per_probe_chain = chain_bytes(chain)
    comparisons = {
        "sh3_float": {"bytes_per_probe": SH3_FLOAT_BYTES,
                      "total_bytes_irradiance_probes": SH3_FLOAT_BYTES * probes_of_kind["irradiance"]},
        **{f"split_sum_{k}": {"bytes_per_probe": v, "total_bytes_reflection_probes": v * probes_of_kind["reflection"]}
           for k, v in per_probe_chain.items()},
    }
    ratios = {}
    for name, e in encodings.items():
        ratios[name] = {
            "vs_sh3_float": e["bytes_per_probe"] / SH3_FLOAT_BYTES,
            **{f"vs_split_sum_{k}": e["bytes_per_probe"] / v for k, v in per_probe_chain.items()},
        }
    tables = shared_tables(store)
    shared_once = sum(t["bytes"] for t in tables)
    return {
        "probes": len(store.probe_names), "probes_of_kind": probes_of_kind, "encodings": encodings,
        "total_bytes_per_kind": per_kind, "total_bytes": sum(per_kind.values()),
        "shared_tables": tables, "shared_bytes": shared_once,
        "total_bytes_with_shared": sum(per_kind.values()) + shared_once,
        "split_sum_chain": {"face_size": chain.face_size, "n_levels": chain.n_levels,
                            "min_face_size": chain.min_face_size, "cube_sizes": chain.cube_sizes(),
                            "octahedral_sizes": chain.octahedral_sizes()},
        "comparisons": comparisons, "ratios": ratios,
    }

"""Baking a USD scene: read it, capture every probe, encode, write the store and the baked-results layer.

    reading = read_scene(scene)            # bakery.usd.scene: probes, lights, dome, meshes (bake frame, metres)
    cubes   = capture_probes(reading)      # bakery.capture: Embree render or captured image, (P, 6, N, N, 3)
    result  = bake_probes(probes, batch)   # bakery.bake: encodings + HDF5 store (atomic)
    layer   = write_bake_layer(...)        # bakery.usd.layer: an ``over`` per probe prim

Scene errors (``bakery check`` severity "error") stop the bake with :class:`bakery.errors.SceneError` before any
output is written; warnings are re-emitted as :class:`bakery.errors.BakeryWarning` and listed in the summary.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from bakery.errors import BakeryWarning, ConfigError, SceneError
from bakery.probe import Probe, ProbeBatch
from bakery.sphere.cubemap import cube_texel_directions, sample_cube_bilinear

SCENE_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")

#: Default rays per cube texel for rendered captures.
DEFAULT_SAMPLES = 4


def default_layer_path(output: Path) -> Path:
    """``<store stem>.bake.usda`` beside the store (never the scene's own file, whatever the store is called)."""
    return output.with_name(f"{output.stem}.bake.usda")


def _to_face_size(cube: np.ndarray, face_size: int) -> np.ndarray:
    """Resample a capture (6, M, M, 3) to the bake grid (6, N, N, 3): box average when M = k·N, else bilinear."""
    m = cube.shape[1]
    if m == face_size:
        return cube
    if m % face_size == 0:
        k = m // face_size
        return cube.reshape(6, face_size, k, face_size, k, 3).mean(axis=(2, 4)).astype(np.float32)
    directions = cube_texel_directions(face_size).reshape(-1, 3)
    return sample_cube_bilinear(cube, directions).reshape(6, face_size, face_size, 3).astype(np.float32)


def bake_scene(
    scene_path: Path,
    output: Path,
    layer_path: Path | None = None,
    face_size: int = 64,
    encodings: list[str] | None = None,
    samples: int = DEFAULT_SAMPLES,
    bounces: int = 1,
    seed: int = 0,
) -> dict:
    """Bake every probe of a USD scene into the store ``output`` and the layer ``layer_path``.

    Args:
        scene_path: .usd/.usda/.usdc/.usdz scene with bakery probe prims.
        output: HDF5 store to write.
        layer_path: baked-results layer (.usda); default :func:`default_layer_path`. Never one of the scene's
            own layers.
        face_size: bake-grid cube face size N.
        encodings: encodings to bake (default: every registered encoding of the probes' kinds); per-probe
            ``bakery:encodings`` are added to them.
        samples: rays per cube texel of rendered captures; bounces: diffuse bounces; seed: base of the per-probe
            seeds (each probe's seed also hashes its prim path).

    Returns:
        A JSON-able summary: probes, store, layer, rays and rays/s, timings, issues.

    Raises:
        SceneError: the scene cannot be opened or has errors (see ``bakery check``).
        ConfigError: invalid settings.
    """
    import time

    from bakery.bake import BakeSettings, bake_probes
    from bakery.capture import ProbeRenderer, load_captured_cube
    from bakery.usd.layer import BakedPrim, attribute_name, write_bake_layer
    from bakery.usd.scene import read_scene

    scene_path, output = Path(scene_path), Path(output)
    if samples < 1 or bounces < 0:
        raise ConfigError(f"samples must be >= 1 and bounces >= 0, got {samples} and {bounces}")
    layer_path = Path(layer_path) if layer_path is not None else default_layer_path(output)
    timings: dict[str, float] = {}

    start = time.perf_counter()
    reading = read_scene(scene_path)
    timings["read_scene"] = time.perf_counter() - start
    if reading.errors:
        listing = "\n".join(f"  {issue}" for issue in reading.errors)
        raise SceneError(f"{scene_path}: {len(reading.errors)} error(s); the bake cannot be trusted:\n{listing}")
    warning_issues = [i for i in reading.issues if i.severity == "warning"]
    for issue in warning_issues:
        warnings.warn(f"{scene_path}: {issue}", BakeryWarning, stacklevel=2)
    protected = reading.layers

    scene = reading.scene
    cubes = np.zeros((len(scene.probes), 6, face_size, face_size, 3), dtype=np.float32)
    renderer: ProbeRenderer | None = None
    rays, render_seconds, rendered, loaded = 0, 0.0, 0, 0
    start = time.perf_counter()
    for i, spec in enumerate(scene.probes):
        n = spec.resolution or face_size
        if spec.image:
            cubes[i] = _to_face_size(load_captured_cube(spec.image, np.asarray(spec.rotation), n), face_size)
            loaded += 1
            continue
        if renderer is None:
            renderer = ProbeRenderer(scene, samples=samples, bounces=bounces, base_seed=seed)
        cube, stats = renderer.render(np.asarray(spec.position), n, spec.name)
        cubes[i] = _to_face_size(cube, face_size)
        rays += stats.rays
        render_seconds += stats.seconds
        rendered += 1
    timings["capture"] = time.perf_counter() - start

    probes = [
        Probe(
            name=spec.name,
            kinds=(spec.kind,),
            position=spec.position,
            settings={k: v for k, v in {"encodings": list(spec.encodings), "volume": spec.volume,
                                        "influence": spec.influence}.items() if v},
        )
        for spec in scene.probes
    ]
    requested = list(encodings or [])
    extra = sorted({e for spec in scene.probes for e in spec.encodings} - set(requested))
    chosen = tuple(requested + extra) if requested else ()
    if not requested and extra:
        from bakery.encodings import ENCODINGS

        kinds = {spec.kind for spec in scene.probes}
        chosen = tuple([n for n, cls in ENCODINGS.items() if cls.kind in kinds] + extra)
        chosen = tuple(dict.fromkeys(chosen))
    settings = BakeSettings(face_size=face_size, encodings=chosen)
    start = time.perf_counter()
    result = bake_probes(
        probes,
        ProbeBatch(cubes),
        settings,
        output,
        attributes={
            "source": str(scene_path),
            "source_kind": "usd",
            "scene_up_axis": reading.up_axis,
            "scene_meters_per_unit": reading.meters_per_unit,
            "capture_samples": samples,
            "capture_bounces": bounces,
            "capture_seed": seed,
        },
    )
    timings["encode_and_store"] = time.perf_counter() - start

    # Group rows per prim (a probe volume's probes share one prim, in flat order).
    prim_rows: dict[str, list[int]] = {}
    for row, spec in enumerate(scene.probes):
        prim_rows.setdefault(spec.volume or spec.name, []).append(row)
    baked: list[BakedPrim] = []
    for prim_path, rows in prim_rows.items():
        fields: dict[str, np.ndarray] = {}
        names: list[str] = []
        for name, values in result.encoded.items():
            index = {int(r): k for k, r in enumerate(result.probe_index[name])}
            if not all(r in index for r in rows):
                continue
            kind = result.encodings[name].kind
            for field_name, array in values.items():
                fields[attribute_name(kind, name, field_name)] = np.asarray(array)[[index[r] for r in rows]]
            names.append(name)
        baked.append(BakedPrim(prim_path, len(rows), tuple(names), fields))
    start = time.perf_counter()
    written = write_bake_layer(
        layer_path, baked, result.store_path, result.settings_hash, scene_path,
        up_axis="Y" if reading.up_axis == "Y" else reading.up_axis, meters_per_unit=reading.meters_per_unit,
        protected=protected,
    )
    timings["write_layer"] = time.perf_counter() - start
    return {
        "scene": str(scene_path),
        "store": str(result.store_path),
        "layer": str(written),
        "probes": len(probes),
        "prims": len(baked),
        "rendered": rendered,
        "loaded_from_images": loaded,
        "face_size": face_size,
        "samples": samples,
        "bounces": bounces,
        "rays": rays,
        "render_seconds": render_seconds,
        "rays_per_second": rays / render_seconds if render_seconds > 0 else 0.0,
        "encodings": sorted(result.encoded),
        "settings_hash": result.settings_hash,
        "timings_s": {**timings, **result.timings},
        "issues": [str(i) for i in reading.issues],
        "warnings": list(result.warnings),
    }


"""bakery: a batch light-probe baker.

Public API (see README):
    bakery.bake(sources, output, ...) -> BakeSummary   # the one bake path (bakery.pipeline.run.bake)
    bakery.open_store(path) -> ProbeStore              # list probes and encodings, evaluate any encoding
"""

from __future__ import annotations

__version__ = "0.1.0"


def open_store(path, lazy=False):  # noqa: ANN001, ANN201, D103 - documented in bakery.api
    from bakery.api import open_store as _open

    return _open(path, lazy=lazy)


def bake(  # noqa: PLR0913 - a façade over BakeRequest
    sources, output, *, recipe=None, encodings=(), face_size=None, encoding_settings=None, layer=None, layout=None,
    jobs=1, executor=None, samples=None, bounces=None, seed=None, resume=True, reference_errors=None,
    quality_directions=None, band_energy_tolerance=None, batch_size=None, target_noise=None, time=None,
    subdivision=None, force=False, progress=None,
):  # noqa: ANN001, ANN201
    """Bake ``sources`` into the store ``output`` through the one bake path and return its ``BakeSummary``.

    Args:
        sources: an environment image path, a list of them, one USD scene path, or a :class:`bakery.sources.Source`
            (e.g. :class:`bakery.sources.CubeSource` for captures in memory).
        output: the HDF5 store to write (atomically).
        recipe: a recipe preset name (``mobile``, ``console``, ``pc-high``, ``reference``) or TOML path; explicit
            arguments override it.
        encodings: encodings to bake (default: the recipe's targets, else every encoding of the probes' kinds).
        face_size: bake-grid face size (default: the recipe's, else the source's default).
        encoding_settings: {encoding: {parameter: value}} merged over the recipe's (validated against each
            encoding's typed ``Params``).
        layer: the baked-results USD layer of a scene bake (default ``<store stem>.bake.usda``).
        jobs: worker processes (1 = in-process); ``executor``: an explicit executor instead.
        samples, bounces, seed, target_noise, time, subdivision: rendered-capture settings (scenes; see
            :class:`bakery.pipeline.settings.CaptureSettings`).
        resume: reuse checkpoints and unchanged probes of an existing store.
        band_energy_tolerance: band skipping ε (None: the recipe's when baking its targets, else no skipping).
        force: let the outputs replace files the output policy refuses (never an input of the bake).

    Raises:
        bakery.errors.BakeryError: bad input (nothing written), bad settings, or no probe could be baked.
    """
    from bakery.pipeline.executors import make_executor
    from bakery.pipeline.run import bake as run_bake
    from bakery.pipeline.settings import request_from

    request = request_from(
        sources, output, recipe=recipe, encodings=encodings or (), face_size=face_size,
        encoding_settings=encoding_settings, layer=layer, layout=layout, samples=samples, bounces=bounces, seed=seed,
        resume=resume, reference_errors=reference_errors, quality_directions=quality_directions,
        band_energy_tolerance=band_energy_tolerance, batch_size=batch_size, target_noise=target_noise, time=time,
        subdivision=subdivision,
    )
    if force:
        from dataclasses import replace

        request = replace(request, force=True)
    own = executor is None
    executor = executor or make_executor(jobs)
    try:
        return run_bake(request, executor, progress)
    finally:
        if own:
            executor.close()

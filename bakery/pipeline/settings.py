"""What a bake is asked to do: :class:`BakeSettings` (hashed into every probe's content hash) and
:class:`BakeRequest` (settings plus inputs, outputs and pipeline options), and the encodings a bake builds from them.

Encoding parameters are resolved in one place (:func:`encoding_params`): the encoding's typed ``Params`` defaults,
then the bake's ``encoding_settings`` for it (validated strictly: wrong type, unknown key or out-of-range value is a
:class:`~bakery.errors.ConfigError`), then per-probe overrides (e.g. a reflection probe's fit roughness range), then
the bake face size for encodings that follow it.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import bakery
from bakery.conventions import MAX_FACE_SIZE, SEED_RANGE
from bakery.encodings import ENCODINGS, Encoding, EncodingParams, get_encoding
from bakery.errors import ConfigError
from bakery.files import stable_hash


@dataclass(frozen=True)
class CaptureSettings:
    """How rendered captures are made (scene sources; part of every rendered probe's content hash).

    Attributes:
        samples: rays per cube texel (≥ 1); with ``target_noise`` the rays of one adaptive pass.
        bounces: largest number of bounces after the first hit (≥ 0); paths end earlier by Russian roulette from
            the third bounce on (``bakery.capture.render``), so the default converges closed rooms.
        seed: base of the per-probe seeds (each probe's seed also hashes its name).
        target_noise: adaptive sampling: add passes of ``samples`` rays per texel until the probe's relative SH
            noise (estimated from its own rays) is below this (0: off).
        max_samples: largest rays per texel of adaptive sampling (0: 64 × samples).
        time: USD time code the stage is read at (None: authored defaults, else the earliest time sample).
        subdivision: catmullClark refinement levels of subdivision meshes (0: their control cage, reported).
    """

    samples: int = 4
    bounces: int = 64
    seed: int = 0
    target_noise: float = 0.0
    max_samples: int = 0
    time: float | None = None
    subdivision: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.samples, bool) or not isinstance(self.samples, int) or self.samples < 1:
            raise ConfigError(f"capture samples must be an integer >= 1, got {self.samples!r}")
        if isinstance(self.bounces, bool) or not isinstance(self.bounces, int) or self.bounces < 0:
            raise ConfigError(f"capture bounces must be an integer >= 0, got {self.bounces!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not (
                SEED_RANGE[0] <= self.seed <= SEED_RANGE[1]):  # stored as the store's int64 capture_seed
            raise ConfigError(f"capture seed must be a 64-bit signed integer (in [{SEED_RANGE[0]}, {SEED_RANGE[1]}]),"
                              f" got {self.seed!r}")
        if isinstance(self.target_noise, bool) or not isinstance(self.target_noise, (int, float)) or not (
                0.0 <= float(self.target_noise) < 1.0):
            raise ConfigError(f"capture target_noise must be a number in [0, 1), got {self.target_noise!r}")
        object.__setattr__(self, "target_noise", float(self.target_noise))
        if isinstance(self.max_samples, bool) or not isinstance(self.max_samples, int) or self.max_samples < 0:
            raise ConfigError(f"capture max_samples must be an integer >= 0, got {self.max_samples!r}")
        if self.time is not None:
            if isinstance(self.time, bool) or not isinstance(self.time, (int, float)) or not math.isfinite(self.time):
                raise ConfigError(f"capture time must be a finite number (a USD time code), got {self.time!r}")
            object.__setattr__(self, "time", float(self.time))
        if isinstance(self.subdivision, bool) or not isinstance(self.subdivision, int) or not (
                0 <= self.subdivision <= 4):
            raise ConfigError(f"capture subdivision must be an integer in [0, 4], got {self.subdivision!r}")


@dataclass(frozen=True)
class BakeSettings:
    """Everything a bake's result depends on besides its inputs (hashed into ``settings_hash``).

    Attributes:
        face_size: bake-grid cube face size N (texels).
        encodings: encoding names to bake; empty = every registered encoding of the probes' kinds.
        encoding_settings: per-encoding parameters {name: {key: value}}, checked against each encoding's ``Params``.
        quality_directions: size of the Fibonacci direction set for negative-share and error diagnostics.
        reference_errors: compute each irradiance encoding's error against the exact reference irradiance.
    """

    face_size: int = 64
    encodings: tuple[str, ...] = ()
    encoding_settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    quality_directions: int = 1024
    reference_errors: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.face_size, bool) or not isinstance(self.face_size, int) or not (
                4 <= self.face_size <= MAX_FACE_SIZE):
            raise ConfigError(f"face_size must be an integer in [4, {MAX_FACE_SIZE}], got {self.face_size!r}")
        if not isinstance(self.quality_directions, int) or self.quality_directions < 4:
            raise ConfigError(f"quality_directions must be an integer >= 4, got {self.quality_directions!r}")
        object.__setattr__(self, "encodings", tuple(self.encodings))
        for name in self.encodings:
            _encoding_class(name)
        for name, values in self.encoding_settings.items():
            cls = _encoding_class(name, where="encoding_settings")
            cls.Params.from_mapping(values, where=f"encoding_settings.{name}")

    def as_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> BakeSettings:
        data = json.loads(text)
        data["encodings"] = tuple(data.get("encodings", ()))
        return cls(**data)

    def hash(self) -> str:
        """sha256 of the canonical settings JSON and bakery's version (the code version is a result input)."""
        return stable_hash(self.as_json(), bakery.__version__)


def _encoding_class(name: str, where: str = "encodings") -> type[Encoding]:
    try:
        return get_encoding(name)
    except KeyError as error:
        raise ConfigError(f"{where}: {error.args[0]}") from None


def encoding_params(name: str, settings: BakeSettings, overrides: Mapping[str, Any] | None = None) -> EncodingParams:
    """The resolved, validated ``Params`` of encoding ``name`` for a bake (module docstring)."""
    cls = _encoding_class(name)
    values = {**settings.encoding_settings.get(name, {}), **(overrides or {})}
    params = cls.Params.from_mapping(values, where=f"encoding_settings.{name}")
    if cls.follows_bake_face_size and getattr(params, "face_size", 0) is None:
        params = params.replace(face_size=settings.face_size)
    return params


def build_encodings(
    names: tuple[str, ...] | list[str], settings: BakeSettings, overrides: Mapping[str, Mapping[str, Any]] | None = None,
) -> dict[str, Encoding]:
    """Encoding instances {name: Encoding} with resolved parameters (``overrides``: per-encoding, per-probe values)."""
    overrides = overrides or {}
    return {name: get_encoding(name)(encoding_params(name, settings, overrides.get(name))) for name in names}


def default_encodings(kinds: set[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Every registered encoding of the given probe kinds, in registration order."""
    return tuple(name for name, cls in ENCODINGS.items() if cls.kind in kinds)


@dataclass(frozen=True)
class BakeRequest:
    """One bake: inputs, outputs, settings and pipeline options (what the CLI and :func:`bakery.bake` build).

    Attributes:
        sources: input files (environment images, or one USD scene), or a :class:`bakery.sources.Source` instance
            (e.g. :class:`bakery.sources.CubeSource` for captures already in memory).
        output: the HDF5 probe store to write.
        settings: what the result depends on.
        capture: rendered-capture settings (scene sources).
        layer: the baked-results USD layer (scene sources; default ``<store stem>.bake.usda``).
        layout: force the environment image layout (``equirect``, ``cube``, ``angular``).
        resume: reuse checkpoints of an interrupted bake and unchanged probes of the existing store.
        band_energy_tolerance: ε of band skipping; None disables skipping (encodings asked for explicitly).
        batch_size: probes per worker batch (None: the source's default).
        force: let the outputs replace existing files the output policy would refuse (a foreign HDF5 file, a
            newer-format or unreadable store, a non-bakery layer); never an input of the bake.
    """

    sources: tuple[Path, ...] | Any
    output: Path
    settings: BakeSettings = field(default_factory=BakeSettings)
    capture: CaptureSettings = field(default_factory=CaptureSettings)
    layer: Path | None = None
    layout: str | None = None
    resume: bool = True
    band_energy_tolerance: float | None = None
    batch_size: int | None = None
    force: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "output", Path(self.output))
        if self.layer is not None:
            object.__setattr__(self, "layer", Path(self.layer))
        if isinstance(self.sources, (str, Path)):
            object.__setattr__(self, "sources", (Path(self.sources),))
        elif isinstance(self.sources, (list, tuple)):
            if not self.sources:
                raise ConfigError("a bake needs at least one source")
            object.__setattr__(self, "sources", tuple(Path(s) for s in self.sources))
        if self.batch_size is not None and (isinstance(self.batch_size, bool) or self.batch_size < 1):
            raise ConfigError(f"batch_size must be >= 1, got {self.batch_size!r}")
        if self.band_energy_tolerance is not None and not 0.0 < float(self.band_energy_tolerance) < 1.0:
            raise ConfigError(f"band_energy_tolerance must be in (0, 1), got {self.band_energy_tolerance!r}")


#: Default ε of band skipping (when a bake follows its recipe's or the default targets): a band is dropped only where
#: the bands above carry < 1e-6 of the irradiance energy (≈ 0.1 % RMS irradiance), i.e. no visible energy.
DEFAULT_BAND_TOLERANCE = 1e-6


def _checked_arguments(sources: Any, output: Any, recipe: Any, encodings: Any, encoding_settings: Any, layer: Any,
                       batch_size: Any, band_energy_tolerance: Any, source_type: type) -> tuple[str, ...]:
    """ConfigError naming the argument for a value of the wrong type (the API's raw TypeErrors and a string of
    encodings split into letters before); returns ``encodings`` as a tuple (one name may be given as a str)."""
    def path_like(value: Any) -> bool:
        return isinstance(value, (str, os.PathLike)) and str(value) != ""

    def kind(value: Any) -> str:
        return f"{type(value).__name__} {value!r}"[:80]

    if not (isinstance(sources, source_type) or path_like(sources) or (
            isinstance(sources, (list, tuple)) and sources and all(path_like(s) for s in sources))):
        raise ConfigError(f"sources must be a file path, a non-empty list of them or a bakery.sources.Source, got "
                          f"{kind(sources)}")
    for name, value in (("output", output), ("recipe", recipe), ("layer", layer)):
        if value is not None and not path_like(value):
            raise ConfigError(f"{name} must be a path (str or os.PathLike), got {kind(value)}")
    if isinstance(encodings, str):
        encodings = (encodings,)
    if not isinstance(encodings, (list, tuple)) or not all(isinstance(n, str) for n in encodings):
        raise ConfigError(f"encodings must be encoding names (a str or a sequence of them), got {kind(encodings)}")
    if encoding_settings is not None and not (isinstance(encoding_settings, Mapping) and all(
            isinstance(k, str) and isinstance(v, Mapping) for k, v in encoding_settings.items())):
        raise ConfigError(f"encoding_settings must map encoding names to {{parameter: value}} mappings, got "
                          f"{kind(encoding_settings)}")
    if batch_size is not None and (isinstance(batch_size, bool) or not isinstance(batch_size, int)):
        raise ConfigError(f"batch_size must be an integer >= 1, got {kind(batch_size)}")
    if band_energy_tolerance is not None and (isinstance(band_energy_tolerance, bool) or not isinstance(
            band_energy_tolerance, (int, float)) or not math.isfinite(band_energy_tolerance)):
        raise ConfigError(f"band_energy_tolerance must be a number in (0, 1), got {kind(band_energy_tolerance)}")
    return tuple(encodings)


def request_from(
    sources: Any, output: str | Path | None = None, *, recipe: str | None = None, encodings: tuple[str, ...] = (),
    face_size: int | None = None, encoding_settings: Mapping[str, Mapping[str, Any]] | None = None,
    layer: str | Path | None = None, layout: str | None = None, samples: int | None = None,
    bounces: int | None = None, seed: int | None = None, resume: bool = True, reference_errors: bool | None = None,
    quality_directions: int | None = None, band_energy_tolerance: float | None = None,
    batch_size: int | None = None, target_noise: float | None = None, time: float | None = None,
    subdivision: int | None = None,
) -> BakeRequest:
    """A :class:`BakeRequest` from a recipe (preset name or TOML path) and explicit overrides, which win.

    The CLI and :func:`bakery.bake` both build their requests here, so the same arguments give the same bake.
    Band skipping applies when the bake follows the recipe's (or the default) targets; encodings asked for
    explicitly are all written (``band_energy_tolerance`` overrides both).
    """
    from bakery.pipeline.recipe import load_recipe
    from bakery.sources import Source, source_for

    encodings = _checked_arguments(sources, output, recipe, encodings, encoding_settings, layer, batch_size,
                                   band_energy_tolerance, Source)
    loaded = load_recipe(str(recipe)) if recipe else None
    bake_options = dict(loaded.bake) if loaded else {}
    pipeline_options = dict(loaded.pipeline) if loaded else {}
    source = sources if isinstance(sources, Source) else None
    if output is None:
        if source is not None or not isinstance(sources, (str, Path, list, tuple)) or not sources:
            raise ConfigError("give an output store path")
        first = Path(sources if isinstance(sources, (str, Path)) else sources[0])
        output = first.with_suffix(".h5")
    merged_settings: dict[str, dict[str, Any]] = {k: dict(v) for k, v in (loaded.encoding_settings if loaded else {}).items()}
    for name, values in (encoding_settings or {}).items():
        merged_settings[name] = {**merged_settings.get(name, {}), **values}
    if face_size is None:
        face_size = bake_options.get("face_size")
    if face_size is None:
        face_size = (source or source_for(sources, layout)).default_face_size
    settings = BakeSettings(
        face_size=face_size,
        encodings=tuple(encodings) or (loaded.encodings if loaded else ()),
        encoding_settings=merged_settings,
        quality_directions=quality_directions if quality_directions is not None
        else bake_options.get("quality_directions", 1024),
        reference_errors=reference_errors if reference_errors is not None
        else bake_options.get("reference_errors", True),
    )
    capture_options = dict(getattr(loaded, "capture", {}) or {}) if loaded else {}
    capture = CaptureSettings(
        samples=samples if samples is not None else capture_options.get("samples", CaptureSettings.samples),
        bounces=bounces if bounces is not None else capture_options.get("bounces", CaptureSettings.bounces),
        seed=seed if seed is not None else CaptureSettings.seed,
        target_noise=target_noise if target_noise is not None else capture_options.get("target_noise", 0.0),
        max_samples=capture_options.get("max_samples", 0),
        time=time if time is not None else capture_options.get("time"),
        subdivision=subdivision if subdivision is not None else capture_options.get("subdivision", 0),
    )
    if band_energy_tolerance is None and not encodings:
        band_energy_tolerance = pipeline_options.get("band_energy_tolerance", DEFAULT_BAND_TOLERANCE)
    return BakeRequest(
        sources=sources, output=Path(output), settings=settings, capture=capture, layer=layer, layout=layout,
        resume=resume, band_energy_tolerance=band_energy_tolerance or None,
        batch_size=batch_size if batch_size is not None else pipeline_options.get("batch_size"),
    )

"""Bake recipes: declarative TOML (presets in ``bakery/pipeline/presets/*.toml``) validated against
``bakery/pipeline/recipe.schema.json``.

A recipe names the encodings to bake per probe kind (``[targets]``), the bake settings (``[bake]``), per-encoding
parameters (``[encoding_settings.<name>]``), pipeline options (``[pipeline]``) and how scenes are captured
(``[capture]``: ``samples``, ``bounces``, ``target_noise``, ``max_samples``, ``time``, ``subdivision``; see
:class:`bakery.pipeline.settings.CaptureSettings`). Unknown keys and unknown
encoding names are errors that say where they are. The JSON Schema checks the recipe's structure; each
``[encoding_settings.<name>]`` table is checked by that encoding's typed ``Params``
(:meth:`bakery.encodings.EncodingParams.from_mapping`: unknown keys, wrong types and out-of-range values).

The schema and the presets are package data: a wheel or ``pip install .`` carries them, as ``pip install -e .`` does.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jsonschema

from bakery.encodings import ENCODINGS
from bakery.errors import ConfigError

SCHEMA_PATH = Path(__file__).resolve().with_name("recipe.schema.json")
RECIPE_DIR = Path(__file__).resolve().parent / "presets"


@dataclass(frozen=True)
class Recipe:
    name: str
    description: str
    targets: dict[str, tuple[str, ...]]
    bake: dict[str, Any] = field(default_factory=dict)
    encoding_settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    pipeline: dict[str, Any] = field(default_factory=dict)
    capture: dict[str, Any] = field(default_factory=dict)
    #: ``[[exports]]`` tables (format, output, profile, probes, options), run after the bake by ``bakery bake``
    exports: tuple[dict[str, Any], ...] = ()

    @property
    def encodings(self) -> tuple[str, ...]:
        return tuple(name for names in self.targets.values() for name in names)


def _schema() -> dict:
    if not SCHEMA_PATH.is_file():
        raise ConfigError(f"recipe JSON Schema not found ({SCHEMA_PATH})")
    return json.loads(SCHEMA_PATH.read_text())


def validate_recipe(data: dict, source: str) -> Recipe:
    """Validate parsed recipe data; raise :class:`ConfigError` naming the file and the offending key."""
    validator = jsonschema.Draft202012Validator(_schema())
    errors = sorted(validator.iter_errors(data), key=lambda e: list(e.absolute_path))
    if errors:
        messages = [f"{'.'.join(map(str, e.absolute_path)) or '<root>'}: {e.message}" for e in errors]
        raise ConfigError(f"{source}: invalid recipe:\n  " + "\n  ".join(messages))
    targets = {kind: tuple(names) for kind, names in data.get("targets", {}).items()}
    for kind, names in targets.items():
        for name in names:
            if name not in ENCODINGS:
                raise ConfigError(f"{source}: targets.{kind}: unknown encoding {name!r}; known: {', '.join(ENCODINGS)}")
            if ENCODINGS[name].kind != kind:
                raise ConfigError(f"{source}: targets.{kind}: {name!r} is a {ENCODINGS[name].kind} encoding")
    for name, values in data.get("encoding_settings", {}).items():
        if name not in ENCODINGS:
            raise ConfigError(f"{source}: encoding_settings.{name}: unknown encoding; known: {', '.join(ENCODINGS)}")
        ENCODINGS[name].Params.from_mapping(values, where=f"{source}: encoding_settings.{name}")
    exports = tuple(dict(e) for e in data.get("exports", []))
    for i, entry in enumerate(exports):  # formats, profiles and options are checked by bakery/export
        from bakery.export import get_format, get_profile

        where = f"{source}: exports[{i}]"
        try:
            cls = get_format(entry["format"])
            get_profile(entry.get("profile") or cls.default_profile)
        except ConfigError as error:
            raise ConfigError(f"{where}: {error}") from None
        cls.Params.from_mapping(entry.get("options", {}), where=where)
    return Recipe(data["name"], data.get("description", ""), targets, data.get("bake", {}),
                  data.get("encoding_settings", {}), data.get("pipeline", {}), data.get("capture", {}), exports)


def load_recipe(name_or_path: str) -> Recipe:
    """A recipe by file path or by preset name (``mobile``, ``console``, ``pc-high``, ``reference``)."""
    path = Path(name_or_path)
    if not path.is_file():
        preset = RECIPE_DIR / f"{name_or_path}.toml"
        path = preset if preset.is_file() else path
    if not path.is_file():
        presets = sorted(p.stem for p in RECIPE_DIR.glob("*.toml")) if RECIPE_DIR.is_dir() else []
        listing = ", ".join(presets) or f"none in {RECIPE_DIR}"
        raise ConfigError(f"recipe {name_or_path!r} not found; presets: {listing}")
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: not a TOML recipe (not UTF-8 text: byte {error.start})") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from None
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the recipe ({error.strerror or error})") from None
    return validate_recipe(data, str(path))

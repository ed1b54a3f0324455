"""Registering bakery's codeless USD schemas with OpenUSD's plugin system.

Where the files live
    ``schemas/usd/schema.usda`` (repository root) is the source. ``usdGenSchema`` turns it into
    ``generatedSchema.usda`` + ``plugInfo.json``; both are kept in ``schemas/usd/`` (usable with
    ``PXR_PLUGINPATH_NAME=schemas/usd``) and copied into this package as ``bakery/usd/schema/`` (package data), so
    the plugin is found the same way from a ``pip install -e .`` and a plain ``pip install .``:
    :func:`register_schemas` calls ``Plug.Registry().RegisterPlugins(<package>/schema)``. ``bakery.usd`` calls it
    on import, before any stage is opened.

Regenerating after editing ``schema.usda`` or adding an encoding or a field (from the repository root)::

    python -m bakery.usd.sync_schemas

The ``BakeryBakedProbeAPI`` attributes of every encoding's fields, ``bakery:<kind>:<encoding>:<field>``, are not
written by hand: :func:`baked_field_block` generates them from the encodings' declarations (the registry, default
parameters, :func:`bakery.usd.layer.usd_type_for` — the type the layer writer uses) between the markers
:data:`BEGIN_GENERATED` / :data:`END_GENERATED` of ``schema.usda``; ``tests/usd/test_usd_schema.py`` fails when the
registry declares a field the schema does not.

OpenUSD builds its schema registry once, on first use; plugins registered after that are not seen by
``UsdSchemaRegistry`` (prim definitions, fallbacks). bakery's scene reader does not rely on the registry: it reads
attributes by name with the schema's fallbacks (:data:`FALLBACKS`), so a late registration only loses
``IsA``-style queries, which :func:`schemas_registered` reports.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Plug, Tf, Usd

from bakery.conventions import MAX_FACE_SIZE
from bakery.files import write_bytes_atomic

#: The packaged plugin directory (plugInfo.json + generatedSchema.usda).
PLUGIN_DIR = Path(__file__).resolve().parent / "schema"

#: Prim type names defined by the schema.
PROBE_TYPES = ("BakeryIrradianceProbe", "BakeryReflectionProbe", "BakeryIrradianceProbeVolume")
BAKED_API = "BakeryBakedProbeAPI"

#: Fallback values of the schema's attributes (must match schemas/usd/schema.usda; checked by the tests).
FALLBACKS: dict[str, object] = {
    "bakery:influence:shape": "sphere",
    "bakery:influence:radius": 5.0,
    "bakery:influence:extent": (5.0, 5.0, 5.0),
    "bakery:influence:blendDistance": 0.5,
    "bakery:capture:resolution": 0,
    "bakery:volume:extent": (1.0, 1.0, 1.0),
    "bakery:volume:counts": (2, 2, 2),
    "bakery:volume:relocate": False,
    "bakery:volume:dilate": False,
    "bakery:volume:dilationDistance": 0.0,
    "bakery:volume:dilationIterations": 1,
}

#: Markers of the generated block of ``schema.usda`` (inside ``BakeryBakedProbeAPI``).
BEGIN_GENERATED = "    # BEGIN generated from bakery.encodings by `python -m bakery.usd.sync_schemas`: do not edit by hand"
END_GENERATED = "    # END generated"

_registered = False


def register_schemas() -> None:
    """Register the packaged plugin with OpenUSD (idempotent)."""
    global _registered
    if _registered:
        return
    if not (PLUGIN_DIR / "plugInfo.json").is_file():
        raise FileNotFoundError(f"bakery's USD plugin is missing: {PLUGIN_DIR / 'plugInfo.json'}")
    Plug.Registry().RegisterPlugins(str(PLUGIN_DIR))
    _registered = True


def schemas_registered() -> bool:
    """Whether OpenUSD's schema registry knows bakery's probe types."""
    return all(
        Usd.SchemaRegistry().FindConcretePrimDefinition(name) is not None for name in PROBE_TYPES
    ) and bool(Tf.Type.FindByName(PROBE_TYPES[0]))


def schema_layouts(cls: type) -> dict[str, dict[str, Any]]:
    """Label → Params overrides of every layout the schema declares for encoding ``cls``: the default settings, its
    :attr:`~bakery.encodings.base.Encoding.schema_layouts`, and, for an encoding whose levels follow the bake's face
    size, each of those at the largest face size a bake accepts (the most levels: a bake at any face size writes
    only declared attributes)."""
    layouts = {"the default settings": {}, **cls.schema_layouts}
    if cls.follows_bake_face_size:
        layouts |= {(f"{label}, " if overrides else "") + f"face_size = {MAX_FACE_SIZE}":
                    {**overrides, "face_size": MAX_FACE_SIZE} for label, overrides in list(layouts.items())}
    return layouts


def baked_field_attributes() -> list[tuple[str, str, str]]:
    """(attribute name, USD type name, documentation) of every field of every registered encoding, with the
    encoding's default parameters, then the fields its other :func:`schema_layouts` add, in registration order."""
    from bakery.encodings import ENCODINGS
    from bakery.usd.layer import MAX_VALUES_PER_PROBE, attribute_name, usd_type_for

    attributes = []
    for cls in ENCODINGS.values():
        seen = set()
        for label, overrides in schema_layouts(cls).items():
            for spec in cls(**overrides).field_specs():
                if spec.name in seen:
                    continue
                seen.add(spec.name)
                type_name = str(usd_type_for(spec.dtype, spec.shape))
                values = int(np.prod(spec.shape, dtype=np.int64))
                shape = "(" + ", ".join(str(d) for d in spec.shape) + ("," if len(spec.shape) == 1 else "") + ")"
                where = label if not overrides else f"{label}, absent at the default settings"
                doc = (f"{cls.kind} encoding {cls.name} {cls.version}, field {spec.name}: {spec.description}; per "
                       f"probe {shape} {spec.dtype} at {where}, written as {type_name} (C order)")
                if values > MAX_VALUES_PER_PROBE:
                    doc += f", store only above {MAX_VALUES_PER_PROBE} values per probe"
                doc += f". Encoding: {cls.description}"
                attributes.append((attribute_name(cls.kind, cls.name, spec.name), type_name, doc))
    return attributes


def runtime_setting_attributes() -> list[tuple[str, str, str]]:
    """(attribute name, USD type name, documentation) of every ``bakery:settings:<encoding>:<key>`` attribute the
    layer writer may write (:func:`bakery.usd.layer.runtime_settings`: the settings the shaders take), uniform."""
    from bakery.encodings import ENCODINGS
    from bakery.usd.layer import runtime_settings, settings_attribute_name

    attributes = []
    for cls in ENCODINGS.values():
        defaults = cls().settings
        for key, (type_name, how) in runtime_settings(cls.name).items():
            default = defaults.get(key)
            if isinstance(default, str) and default in how.get("values", {}):
                default = f"{default!r} = {how['values'][default]}"
            elif isinstance(default, list):
                default = "[" + ", ".join(f"{v:.6g}" for v in default) + "]"
            doc = (f"{cls.kind} encoding {cls.name} {cls.version}, runtime setting {key} ({how['use']}): the value "
                   f"of the store's /encodings/{cls.name} settings {key}, written as uniform {type_name} "
                   f"(at the default parameters {default}; schemas/store*.md, bakery/shaders/manifest.json)")
            attributes.append((settings_attribute_name(cls.name, key), str(type_name), doc))
    return attributes


def baked_field_block() -> str:
    """The generated block of ``schema.usda``: one attribute declaration per :func:`baked_field_attributes` and
    per :func:`runtime_setting_attributes` (uniform)."""
    lines = [BEGIN_GENERATED]
    settings = [(f"uniform {t}", n, d) for n, t, d in runtime_setting_attributes()]
    for name, type_name, doc in [*baked_field_attributes(), *((n, t, d) for t, n, d in settings)]:
        text = doc.replace("\\", "\\\\").replace('"', "'")
        lines += [f"    {type_name} {name} (",
                  f'        doc = """{text}"""',
                  f'        customData = {{ string userDocBrief = """{text}""" }}',
                  "    )"]
    lines.append(END_GENERATED)
    return "\n".join(lines) + "\n"


def update_schema_source(text: str) -> str:
    """``schema.usda`` text with its generated block replaced by :func:`baked_field_block`."""
    start = text.find(BEGIN_GENERATED)
    end = text.find(END_GENERATED)
    if start < 0 or end < start:
        raise ValueError("schema.usda has no generated block (BEGIN/END markers inside BakeryBakedProbeAPI)")
    return text[:start] + baked_field_block() + text[end + len(END_GENERATED) + 1:]


def _fix_plug_info(path: Path) -> None:
    """Replace the CMake placeholders usdGenSchema leaves in plugInfo.json with a resource-only plugin's paths."""
    text = path.read_text()
    header = "".join(line + "\n" for line in text.splitlines() if line.startswith("#"))
    info = json.loads("\n".join(line for line in text.splitlines() if not line.startswith("#")))
    for plugin in info["Plugins"]:
        plugin["LibraryPath"] = ""
        plugin["ResourcePath"] = "."
        plugin["Root"] = "."
    path.write_text(header + json.dumps(info, indent=4, sort_keys=True) + "\n")


def sync_schemas(source_dir: Path) -> None:
    """Regenerate the encoding-field block of ``source_dir/schema.usda`` from the registry, run usdGenSchema on it
    and write the results to ``source_dir`` and :data:`PLUGIN_DIR`."""
    source_dir = Path(source_dir)
    schema = source_dir / "schema.usda"
    text = schema.read_text()
    updated = update_schema_source(text)
    if updated != text:
        write_bytes_atomic(schema, updated.encode())
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "pxr.Usd.usdGenSchema", str(source_dir / "schema.usda"), tmp],
            check=True,
            capture_output=True,
        )
        _fix_plug_info(Path(tmp) / "plugInfo.json")
        for name in ("plugInfo.json", "generatedSchema.usda"):
            data = (Path(tmp) / name).read_bytes()
            write_bytes_atomic(source_dir / name, data)
            write_bytes_atomic(PLUGIN_DIR / name, data)


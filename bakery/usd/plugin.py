"""Registering bakery's codeless USD schemas with OpenUSD's plugin system.

Where the files live
    ``schemas/usd/schema.usda`` (repository root) is the source. ``usdGenSchema`` turns it into
    ``generatedSchema.usda`` + ``plugInfo.json``; both are kept in ``schemas/usd/`` (usable with
    ``PXR_PLUGINPATH_NAME=schemas/usd``) and copied into this package as ``bakery/usd/schema/`` (package data), so
    the plugin is found the same way from a ``pip install -e .`` and a plain ``pip install .``:
    :func:`register_schemas` calls ``Plug.Registry().RegisterPlugins(<package>/schema)``. ``bakery.usd`` calls it
    on import, before any stage is opened.

Regenerating after editing ``schema.usda`` (from the repository root)::

    python -m bakery.usd.sync_schemas

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

from pxr import Plug, Tf, Usd

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
}

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
    """Run usdGenSchema on ``source_dir/schema.usda``; write the results to ``source_dir`` and :data:`PLUGIN_DIR`."""
    source_dir = Path(source_dir)
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


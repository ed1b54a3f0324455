"""bakery's shader library (package data): GLSL ES 3.00 / WebGL2 and HLSL functions that decode and evaluate every
stored encoding exactly as ``schemas/store-v1.md`` and ``schemas/store-reflection.md`` specify.

Files
    bakery_core.glsl        the implementation, written once for both languages through ``BK_*`` macros
    bakery_glsl.glsl        GLSL prelude (precision, macros); concatenate prelude + core + bakery_textures.glsl
    bakery_textures.glsl    GLSL texture lookups (DFG table, split-sum face arrays, cube maps)
    bakery.hlsl             HLSL entry: macros, ``#include`` of the core and bakery_textures.hlsl
    manifest.json           encoding name → entry point and its arguments (fields, settings, inputs, tables)

``tests/shaders/`` renders every manifest entry on a WebGL2 pipeline (headless Chromium) against
``ProbeStore.evaluate_irradiance`` / ``evaluate_reflection``, in GLSL and in HLSL (compiled to SPIR-V by glslang,
translated to GLSL ES 3.00 by spirv-cross, run on the same page). How an engine uses them: ``docs/engine-integration.md``.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

#: The folder holding the shader files.
SHADER_DIR = Path(__file__).resolve().parent


@cache
def manifest() -> dict:
    """The parsed ``manifest.json``."""
    return json.loads((SHADER_DIR / "manifest.json").read_text())


def glsl_library() -> str:
    """The GLSL library as one string (prelude + core + textures), to follow a ``#version 300 es`` line."""
    return "\n".join((SHADER_DIR / name).read_text() for name in manifest()["sources"]["glsl"])


def entry_for(encoding: str, settings: dict) -> dict | None:
    """The manifest entry ({"entry", "arguments"}) for an encoding with the given stored settings, or None."""
    spec = manifest()["encodings"].get(encoding)
    if spec is None:
        return None
    for variant in spec.get("variants", ()):
        if all(settings.get(key) == value for key, value in variant["when"].items()):
            return variant
    return spec

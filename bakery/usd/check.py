"""``bakery check``: problems of a USD scene, per prim, triaged like ``usdchecker``.

Outcomes
    *could not run*  the stage cannot be opened: one "error" issue on "/" (the CLI exits non-zero);
    *failed*         any "error" issue: the bake refuses to run (its result could not be trusted);
    *warnings*       what a bake would silently change: documented fallbacks and approximations (textures averaged
                     where a mesh has no texture coordinates, unreadable or missing textures, float textures without
                     colour-space information, unmodelled material lobes and normal maps,
                     subdivision surfaces baked as their cage, unsupported gprims, light types and light inputs,
                     unauthored metersPerUnit, ...).

Checks are those of the scene reader (:mod:`bakery.usd.scene`) — the same code the bake runs, so ``check`` and
``bake`` never disagree — including the stage's composition errors (a sublayer that fails to parse, an
unresolvable reference or payload), which are errors: their contents would silently be missing from the bake.
"""

from __future__ import annotations

from pathlib import Path

from bakery.errors import CHECK_FAILED_EXIT_CODE, SceneError
from bakery.usd.scene import Issue, SceneReader, open_stage

__all__ = ["Issue", "check_scene", "check_exit_code"]


def check_scene(path: str | Path) -> list[Issue]:
    """Every problem found in the scene at ``path``, errors first, then by prim path."""
    try:
        stage = open_stage(path)
    except SceneError as exc:
        return [Issue("error", "/", str(exc))]
    issues: list[Issue] = list(SceneReader(stage, load_textures=True).read().issues)
    order = {"error": 0, "warning": 1}
    return sorted(dict.fromkeys(issues), key=lambda i: (order.get(i.severity, 2), i.prim))


def check_exit_code(issues: list[Issue]) -> int:
    """0 when no issue is an error (warnings allowed), else :data:`bakery.errors.CHECK_FAILED_EXIT_CODE`."""
    return CHECK_FAILED_EXIT_CODE if any(i.severity == "error" for i in issues) else 0

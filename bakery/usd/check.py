"""``bakery check``: problems of a USD scene, per prim, triaged like ``usdchecker``.

Outcomes
    *could not run*  the stage cannot be opened: one "error" issue on "/" (the CLI exits non-zero);
    *failed*         any "error" issue: the bake refuses to run (its result could not be trusted);
    *warnings*       what a bake would silently change: documented fallbacks and approximations (textures read at
                     the primvar reader's fallback st where a mesh has no texture coordinates, unreadable or
                     missing textures, float textures without colour-space information, unmodelled material lobes
                     and normal maps,
                     subdivision surfaces baked as their cage, unsupported gprims, light types and light inputs,
                     unauthored metersPerUnit, probes inside geometry, ...).

Checks are those of the scene reader (:mod:`bakery.usd.scene`) — the same code the bake runs, so ``check`` and
``bake`` never disagree — including the stage's composition errors (a sublayer that fails to parse, an
unresolvable reference or payload), which are errors: their contents would silently be missing from the bake —
and a pre-flight of probe validity: each rendered probe's share of :data:`SEARCH_DIRECTIONS` rays that see back
faces (:mod:`bakery.capture.validity`, the measure the bake's capture reports), a warning per probe (per volume:
how many, the first ones) at or above :data:`bakery.conventions.INSIDE_BACKFACE_FRACTION`.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from pxr import Sdf, Usd

from bakery.capture.scene import CaptureScene
from bakery.conventions import INSIDE_BACKFACE_FRACTION
from bakery.errors import CHECK_FAILED_EXIT_CODE, SceneError
from bakery.usd.scene import Issue, SceneReader, defining_layer, open_stage

__all__ = ["Issue", "check_scene", "check_exit_code"]


def check_scene(path: str | Path) -> list[Issue]:
    """Every problem found in the scene at ``path``, errors first, then by prim path."""
    try:
        stage = open_stage(path)
    except SceneError as exc:
        return [Issue("error", "/", str(exc))]
    reading = SceneReader(stage, load_textures=True).read()
    issues: list[Issue] = list(reading.issues) + inside_geometry_issues(reading.scene)
    order = {"error": 0, "warning": 1}
    issues = [replace(i, layer=defining_layer(stage, i.prim)) for i in dict.fromkeys(issues)]  # probes' too
    return sorted(issues, key=lambda i: (order.get(i.severity, 2), i.prim))


def inside_geometry_issues(scene: CaptureScene, shown: int = 3) -> list[Issue]:
    """Warnings for the rendered probes of ``scene`` whose backface fraction over the relocation search's rays is
    ≥ the threshold: one per probe prim, one per volume (count and first members); volumes that relocate or dilate
    say so."""
    from bakery.capture.validity import SEARCH_DIRECTIONS, Relocator  # Embree: only with probes and geometry

    probes = [p for p in scene.probes if not p.image]
    if not probes or not scene.meshes:
        return []
    relocator = Relocator.of_scene(scene)
    inside: dict[str, list[tuple[str, float]]] = {}
    relocating: dict[str, bool] = {}
    dilating: dict[str, bool] = {}
    for spec in probes:
        fraction = relocator.backface_fraction(spec.position)
        if fraction >= INSIDE_BACKFACE_FRACTION:
            inside.setdefault(spec.volume or spec.name, []).append((spec.name, fraction))
            relocating[spec.volume or spec.name] = spec.relocate > 0
            dilating[spec.volume or spec.name] = spec.dilation > 0
    issues = []
    rule = f"≥ {INSIDE_BACKFACE_FRACTION:.0%} of {SEARCH_DIRECTIONS} rays see the back of single-sided surfaces"
    for prim, members in inside.items():
        if members[0][0] == prim:  # a probe prim
            issues.append(Issue("warning", prim, f"the probe is likely inside geometry ({members[0][1]:.0%}: {rule}); "
                                "move it, or author doubleSided on open sheets seen from both sides"))
            continue
        names = ", ".join(f"{name} {fraction:.0%}" for name, fraction in members[:shown])
        more = f" and {len(members) - shown} more" if len(members) > shown else ""
        done = [what for what, on in (("relocates", relocating[prim]), ("dilates", dilating[prim])) if on]
        fix = (f"the bake {' and then '.join(done)} them (bakery:volume:{'relocate' if relocating[prim] else 'dilate'}"
               f"{', bakery:volume:dilate' if len(done) == 2 else ''})" if done else
               "set bakery:volume:relocate or bakery:volume:dilate, move the volume, or author doubleSided on open "
               "sheets")
        issues.append(Issue("warning", prim, f"{len(members)} of its probes {'is' if len(members) == 1 else 'are'} likely inside geometry ({rule}: "
                            f"{names}{more}); {fix}"))
    return issues


def check_exit_code(issues: list[Issue]) -> int:
    """0 when no issue is an error (warnings allowed), else :data:`bakery.errors.CHECK_FAILED_EXIT_CODE`."""
    return CHECK_FAILED_EXIT_CODE if any(i.severity == "error" for i in issues) else 0

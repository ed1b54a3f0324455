"""``bakery check``: problems of a USD scene, per prim, triaged like ``usdchecker``.

Outcomes
    *could not run*  the stage cannot be opened: one "error" issue on "/" (the CLI exits non-zero);
    *failed*         any "error" issue: the bake refuses to run (its result could not be trusted);
    *warnings*       documented fallbacks (MaterialX-only materials, missing material textures, unapplied
                     color temperature, unsupported gprims or lights, unauthored metersPerUnit, ...).

Checks are those of the scene reader (:mod:`bakery.usd.scene`) — the same code the bake runs, so ``check`` and
``bake`` never disagree — plus the stage's composition errors (unresolvable references, payloads, sublayers) as
warnings.
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
    issues: list[Issue] = []
    for error in stage.GetCompositionErrors():
        text = str(error).splitlines()[0] if str(error) else type(error).__name__
        site = getattr(error, "rootSite", None)
        prim = str(site.path) if site is not None and str(getattr(site, "path", "")) else "/"
        issues.append(Issue("warning", prim, f"composition: {text}"))
    reading = SceneReader(stage, load_textures=True).read()
    issues.extend(reading.issues)
    order = {"error": 0, "warning": 1}
    return sorted(dict.fromkeys(issues), key=lambda i: (order.get(i.severity, 2), i.prim))


def check_exit_code(issues: list[Issue]) -> int:
    """0 when no issue is an error (warnings allowed), else :data:`bakery.errors.CHECK_FAILED_EXIT_CODE`."""
    return CHECK_FAILED_EXIT_CODE if any(i.severity == "error" for i in issues) else 0

"""Bake inputs behind one protocol (:mod:`bakery.sources.base`): importing this package registers every source.

    environment   EnvironmentSource   environment images as distant probes        (bakery.sources.environment)
    usd           UsdSceneSource      probe prims of a USD stage, rendered        (bakery.sources.usd_scene)
    cubes         CubeSource          captures already in memory                  (bakery.sources.captures)
"""

from pathlib import Path

from bakery.sources.base import SOURCES, Capture, PlannedProbe, Source, SourceHandle, SourcePlan, source_class
from bakery.sources.captures import CubeSource
from bakery.sources.environment import EnvironmentSource
from bakery.sources.usd_scene import SCENE_SUFFIXES, UsdSceneSource, default_layer_path


def source_for(sources, layout=None, capture=None) -> Source:  # noqa: ANN001
    """The source of a request's inputs: a :class:`Source` as is, one USD scene, or environment images."""
    from bakery.errors import ConfigError

    if isinstance(sources, Source):
        return sources
    paths = (Path(sources),) if isinstance(sources, (str, Path)) else tuple(Path(s) for s in sources)
    scenes = [p for p in paths if p.suffix.lower() in SCENE_SUFFIXES]
    if scenes:
        if len(paths) > 1:
            raise ConfigError("bake one USD scene at a time (and no environment images with it)")
        return UsdSceneSource(paths[0], capture)
    return EnvironmentSource(paths, layout)


__all__ = ["SOURCES", "SCENE_SUFFIXES", "Capture", "CubeSource", "EnvironmentSource", "PlannedProbe", "Source",
           "SourceHandle", "SourcePlan", "UsdSceneSource", "default_layer_path", "source_class", "source_for"]

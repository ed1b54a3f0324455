"""USD front end: bakery's probe schemas, reading scenes, checking them and writing baked layers.

The only package of bakery that imports ``pxr``. Importing it registers bakery's schema plugin
(:func:`bakery.usd.plugin.register_schemas`) so that it happens before the first stage is opened.

Modules
    plugin   schema plugin registration
    scene    stage → :class:`bakery.capture.scene.CaptureScene` (probes, lights, dome, meshes, materials)
    materials  UsdPreviewSurface / MaterialX → the capture's material model, textures as arrays
    mtlx     MaterialX documents and shaders (the ``MaterialX`` package)
    color    colour management into linear Rec.709 (OpenColorIO)
    check    ``check_scene(path) -> list[Issue]`` (what ``bakery check`` prints)
    layer    the baked-results layer (``over`` per probe prim) and reading it back
"""

from bakery.usd.plugin import register_schemas

register_schemas()

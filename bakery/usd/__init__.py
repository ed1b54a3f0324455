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

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def _ctrl_c_held() -> Iterator[None]:
    """A Ctrl-C (SIGINT) that arrives inside the block is held and raised as ``KeyboardInterrupt`` when it ends.

    OpenUSD imports the Python modules of the libraries a pxr module depends on from C++ (Tf's script-module loader)
    and turns any exception there — a ``KeyboardInterrupt`` included — into a warning (``Error loading lib ar's
    module 'pxr.Ar'``): a Ctrl-C while pxr loaded was lost, and the bake went on with a partly loaded pxr and wrote
    its outputs. A no-op outside the main thread and where SIGINT has no Python handler (ignored, default)."""
    if threading.current_thread() is not threading.main_thread() or not callable(signal.getsignal(signal.SIGINT)):
        yield
        return
    held: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if held:
            previous(signal.SIGINT, None)


with _ctrl_c_held():
    # Every pxr module bakery uses, loaded here at once (≈ 0.2 s) with Ctrl-C held: later imports find them loaded.
    from pxr import Ar, Gf, Plug, Sdf, Sdr, Tf, Usd, UsdGeom, UsdLux, UsdShade, UsdSkel, Vt  # noqa: F401

    from bakery.usd.plugin import register_schemas

    register_schemas()

"""bakery: a batch light-probe baker.

Public API (see README):
    bakery.open_store(path) -> ProbeStore   # list probes and encodings, evaluate any encoding at directions
"""

__version__ = "0.1.0"


def open_store(path):  # noqa: D103 - documented in bakery.api
    from bakery.api import open_store as _open

    return _open(path)

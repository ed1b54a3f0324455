"""Encodings: importing this package registers every encoding in :data:`bakery.encodings.registry.ENCODINGS`."""

from bakery.encodings import irradiance  # noqa: F401
from bakery.encodings.registry import ENCODINGS, Encoding, FieldSpec, get_encoding, register

try:  # reflection encodings (issue 3) register themselves when present
    from bakery.encodings import reflection  # noqa: F401
except ImportError:  # pragma: no cover - only while the module is being written
    pass

__all__ = ["ENCODINGS", "Encoding", "FieldSpec", "get_encoding", "register"]

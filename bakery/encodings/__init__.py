"""Encodings, one module per method; importing this package registers every one in
:data:`bakery.encodings.registry.ENCODINGS` (in this order).

    module                         encodings
    -----------------------------  ----------------------------------------------------------------
    :mod:`bakery.encodings.sh`         sh2, sh3
    :mod:`bakery.encodings.zh3`        zh3, zh3_solved, zh3_deringed, zh3_hallucinated
    :mod:`bakery.encodings.quantized`  zh3_quantized, sh3_quantized
    :mod:`bakery.encodings.splitsum`   splitsum
    :mod:`bakery.encodings.shexp`      shexp, shexp_lights
    :mod:`bakery.encodings.hybrid`     shexp_hybrid

The contract (declaration, capabilities, typed Params) is in :mod:`bakery.encodings.base`. The modules are imported
explicitly: a broken encoding module fails this import loudly.
"""

from bakery.encodings.base import Encoding, EncodingParams, FieldSpec, NoParams, ParamsError, finalize_field
from bakery.encodings.registry import ENCODINGS, get_encoding, register

from bakery.encodings import sh  # noqa: E402,F401  (registration order = this order)
from bakery.encodings import zh3  # noqa: E402,F401
from bakery.encodings import zh3_hallucinated_solved  # noqa: E402,F401
from bakery.encodings import quantized  # noqa: E402,F401
from bakery.encodings import splitsum  # noqa: E402,F401
from bakery.encodings import shexp  # noqa: E402,F401
from bakery.encodings import hybrid  # noqa: E402,F401

__all__ = ["ENCODINGS", "Encoding", "EncodingParams", "FieldSpec", "NoParams", "ParamsError", "finalize_field",
           "get_encoding", "register"]

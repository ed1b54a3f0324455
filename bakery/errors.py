"""Errors and warnings of bakery.

Library code never prints or exits: it raises a :class:`BakeryError` subclass (the CLI maps ``exit_code`` to the
process exit status) or emits a :class:`BakeryWarning` subclass for documented clamps and fallbacks, which callers
count and record in the store.
"""

from __future__ import annotations

import warnings


#: Exit status of ``bakery check`` when the scene has errors.
CHECK_FAILED_EXIT_CODE = 5


class BakeryError(Exception):
    """Base of every error bakery raises on purpose. ``exit_code`` is the CLI's exit status for it."""

    exit_code = 1


class InputError(BakeryError):
    """An input file (image, scene, store) is missing, unreadable, truncated or malformed."""

    exit_code = 2


class ImageError(InputError):
    """An environment image cannot be read or has an unsupported layout."""


class SceneError(InputError):
    """A USD scene or one of its prims cannot be baked."""


class StoreFormatError(InputError):
    """A probe store is not a bakery store, is corrupt, or has a format version this reader does not support."""


class ConfigError(BakeryError):
    """Settings or a recipe are invalid."""

    exit_code = 3


class EncodingError(BakeryError):
    """An encoding could not be computed for a probe."""

    exit_code = 4


class ArgumentError(ConfigError, ValueError):
    """An argument of a Python API call is invalid (wrong type, shape or range): the message names the argument and
    says what is wrong. A :class:`ConfigError` (exit code 3) and, like
    :class:`bakery.encodings.base.ParamsError`, a ValueError."""


class EvaluationError(ArgumentError):
    """Invalid inputs of an evaluation (``normals``; ``view``, ``normal``, ``alpha``, ``f0``; ``probes``). A ValueError:
    ``schemas/store-reflection.md`` ("Evaluation inputs") documents ``ValueError`` naming ``alpha``."""


class EncodingKindError(ArgumentError, NotImplementedError):
    """An encoding was evaluated as the other kind (irradiance evaluation of a reflection encoding or vice versa);
    the message names the encoding, its kind and the method to use. Also a NotImplementedError (what the encoding
    base class raised before)."""


class _NamedLookupError(BakeryError, KeyError):
    """A BakeryError that is also a KeyError (what dictionary-style lookups raised before), printed as its message:
    ``str()`` of a plain KeyError would quote it."""

    exit_code = 2

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class UnknownEncodingError(_NamedLookupError):
    """An encoding name that a store does not hold, or that this bakery does not know (a store written by a newer
    version may hold encodings this one cannot evaluate)."""


class UnknownProbeError(_NamedLookupError):
    """A probe name that a store (or one of its encodings) does not hold."""


class BakeryWarning(UserWarning):
    """Base of bakery's warnings: a documented clamp, fallback or suspicious input."""


def warn_about_probes(message: str, category: type[BakeryWarning], rows, stacklevel: int = 2) -> None:
    """Warn about some probes of the batch an encoding was given: ``rows`` (indices into that batch) ride on the
    warning as ``probe_rows``, and the bake names those probes at the end of the message
    (:func:`bakery.pipeline.encode.encode_batch`); called outside a bake, the message stands alone."""
    warning = category(message)
    warning.probe_rows = tuple(int(row) for row in rows)
    warnings.warn(warning, stacklevel=stacklevel + 1)


class SanitizedInputWarning(BakeryWarning):
    """Non-finite or negative radiance was replaced; the counts are recorded in the store."""


class ClampWarning(BakeryWarning):
    """A value was clamped to a documented range (e.g. a float format's maximum)."""


class SceneWarning(BakeryWarning):
    """A scene problem that the bake works around (unsupported light feature, MaterialX-only material, …)."""


class UnsupportedEncodingWarning(BakeryWarning):
    """A store holds an encoding this bakery cannot evaluate (unknown, or a newer major version); it was skipped."""


class DegenerateInputWarning(BakeryWarning):
    """An input is degenerate (black environment, zero-length axis) and a documented fallback was used."""

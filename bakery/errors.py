"""Errors and warnings of bakery.

Library code never prints or exits: it raises a :class:`BakeryError` subclass (the CLI maps ``exit_code`` to the
process exit status) or emits a :class:`BakeryWarning` subclass for documented clamps and fallbacks, which callers
count and record in the store.
"""

from __future__ import annotations


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


class BakeryWarning(UserWarning):
    """Base of bakery's warnings: a documented clamp, fallback or suspicious input."""


class SanitizedInputWarning(BakeryWarning):
    """Non-finite or negative radiance was replaced; the counts are recorded in the store."""


class ClampWarning(BakeryWarning):
    """A value was clamped to a documented range (e.g. a float format's maximum)."""


class SceneWarning(BakeryWarning):
    """A scene problem that the bake works around (unsupported light feature, MaterialX-only material, …)."""


class DegenerateInputWarning(BakeryWarning):
    """An input is degenerate (black environment, zero-length axis) and a documented fallback was used."""

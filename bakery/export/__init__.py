"""Export formats engines and viewers load directly (``bakery export``; ``docs/exports.md``).

Importing this package registers every format (one module each; see :mod:`bakery.export.base`)."""

from bakery.export import filament, gltf, ktx2, three  # noqa: F401 - registration
from bakery.export.base import EXPORT_FORMATS, ExportFormat, ExportResult, export_store, get_format, register_format
from bakery.export.profiles import PROFILES, Profile, get_profile

__all__ = ["EXPORT_FORMATS", "PROFILES", "ExportFormat", "ExportResult", "Profile", "export_store", "get_format",
           "get_profile", "register_format"]

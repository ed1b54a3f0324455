"""Reading USD attribute values with the type their schema (or shader definition) declares.

USD returns an opinion of another type than the schema declares as authored (``string bakery:volume:relocate =
"no"`` reads as a truthy "no", ``float inputs:diffuseColor = 0.5`` as one float where a colour is expected):
:func:`typed_value` reads an attribute with its declared type and raises :class:`~bakery.errors.SceneError` naming
the attribute, its authored and its expected type otherwise. Floating-point precision and roles aside: a ``double``
authored for a ``float``, a ``float3`` for a ``color3f`` and a ``token`` for a ``string`` read the same.
"""

from __future__ import annotations

import re

from pxr import Sdf, Usd

from bakery.errors import SceneError

#: Floating-point precisions of one kind of value (:func:`value_kind`): a double authored for a float reads the same
_REAL_TYPES = {"float": "real", "double": "real", "half": "real", "GfHalf": "real", "pxr_half::half": "real",
               "string": "text", "std::string": "text", "TfToken": "text"}


def value_kind(type_name: Sdf.ValueTypeName) -> tuple[str, bool]:
    """What a USD value type holds, for type checks: its scalar type without role or floating-point precision
    (float, double and half → "real"; string and token → "text"; GfVec3f/d/h → "GfVec3"; GfQuatf/d/h → "GfQuat"),
    and whether it is an array."""
    scalar = str(type_name.scalarType.type.typeName)
    scalar = _REAL_TYPES.get(scalar) or re.sub(r"^(Gf[A-Za-z]+\d?)[dfh]$", r"\1", scalar)
    return scalar, bool(type_name.isArray)


def authored_type(attr: Usd.Attribute, time: Usd.TimeCode) -> Sdf.ValueTypeName | None:
    """The type of the strongest opinion holding a value of ``attr`` (what the layer authored: for an attribute a
    schema declares, ``attr.GetTypeName()`` is the schema's type whatever the layer says)."""
    stack = attr.GetPropertyStack(time)
    for spec in stack:
        if spec.HasDefaultValue() or spec.layer.GetNumTimeSamplesForPath(spec.path):
            return spec.typeName
    return stack[0].typeName if stack else None


def typed_value(attr: Usd.Attribute, time: Usd.TimeCode, expected: Sdf.ValueTypeName | None = None):
    """The value of ``attr`` at ``time`` (None if it has none), of the type its schema declares: ``expected``, else
    ``attr.GetTypeName()``. USD returns an opinion of another type as authored (``string bakery:volume:relocate =
    "no"`` reads as the truthy "no", ``float`` 2.5 for an ``int`` as 2.5): raises SceneError naming the attribute,
    its authored type and the expected one. Floating-point precision and role aside: a ``double3`` authored for a
    ``color3f`` reads the same."""
    value = attr.Get(time)
    expected = expected or attr.GetTypeName()
    if value is None or not expected or type(value) is type(expected.defaultValue):
        return value
    authored = authored_type(attr, time)
    if authored and value_kind(authored) == value_kind(expected):
        return value
    what = str(authored) if authored else type(value).__name__
    raise SceneError(f"{attr.GetName()} is authored as {what} {shown(value)}, expected {expected}")


def shown(value: object) -> str:
    """A short text of an attribute value for messages: ``'no'``, ``2.5``, ``(2.7, 2, 2)``, ``@sky.hdr@``."""
    if isinstance(value, Sdf.AssetPath):
        text = f"@{value.path}@"
    elif isinstance(value, float):
        text = f"{value:g}"
    elif isinstance(value, str) or not hasattr(value, "__len__"):
        text = repr(value)
    else:
        try:
            text = "(" + ", ".join(f"{float(x):g}" for x in value) + ")"
        except (TypeError, ValueError):
            text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."

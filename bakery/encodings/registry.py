"""The encoding registry: name → class, filled by :func:`register` at the bottom of every encoding module.

Registration is loud: a duplicate name, an unknown kind, a missing or malformed ``Params``, an abstract class or an
inconsistent capability declaration raise ValueError at import time, so a broken encoding module fails the import
of :mod:`bakery.encodings` instead of silently disappearing.
"""

from __future__ import annotations

import dataclasses
import inspect

from bakery.encodings.base import Encoding, EncodingParams

#: The kinds of probe an encoding can be for.
KINDS = ("irradiance", "reflection")

#: name → encoding class, in registration order.
ENCODINGS: dict[str, type[Encoding]] = {}


def _check(cls: type) -> None:
    label = getattr(cls, "__qualname__", repr(cls))
    if not (isinstance(cls, type) and issubclass(cls, Encoding)):
        raise ValueError(f"{label} is not an Encoding subclass")
    name = cls.__dict__.get("name")
    if not isinstance(name, str) or not name:
        raise ValueError(f"encoding {label} does not declare its own name")
    if getattr(cls, "kind", None) not in KINDS:
        kind = getattr(cls, "kind", None)
        raise ValueError(f"encoding {name!r} has unknown kind {kind!r}; kinds: {', '.join(KINDS)}")
    params = cls.__dict__.get("Params")
    if not (isinstance(params, type) and issubclass(params, EncodingParams)):
        raise ValueError(f"encoding {name!r} does not declare Params (an EncodingParams dataclass, e.g. NoParams)")
    if "__dataclass_fields__" not in params.__dict__ or not params.__dataclass_params__.frozen:
        raise ValueError(f"encoding {name!r}: {params.__qualname__} must be decorated @dataclass(frozen=True)")
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(cls.__abstractmethods__))
        raise ValueError(f"encoding {name!r} does not implement {missing}")
    fields = {f.name: f for f in dataclasses.fields(params)}
    if cls.kind == "irradiance" and not (isinstance(cls.max_band, int) and cls.max_band >= 0):
        raise ValueError(f"irradiance encoding {name!r} must declare max_band (the highest SH band it stores)")
    if cls.kind == "reflection" and cls.max_band is not None:
        raise ValueError(f"reflection encoding {name!r} must have max_band None")
    if cls.accepts_alpha_range and not {"alpha_min", "alpha_max"} <= set(fields):
        raise ValueError(f"encoding {name!r} accepts_alpha_range but its Params lack alpha_min/alpha_max")
    if cls.follows_bake_face_size and ("face_size" not in fields or fields["face_size"].default is not None):
        raise ValueError(f"encoding {name!r} follows_bake_face_size but its Params lack face_size = None")
    worse = cls.worse_than
    if worse is not None and not (isinstance(worse, tuple) and len(worse) == 2 and isinstance(worse[0], str)
                                  and isinstance(worse[1], type) and issubclass(worse[1], Encoding)):
        raise ValueError(f"encoding {name!r}: worse_than must be (diagnostic name, Encoding class), got {worse!r}")


def register(*classes: type[Encoding]) -> type[Encoding] | tuple[type[Encoding], ...]:
    """Add encoding classes to :data:`ENCODINGS` (all or none). Returns the class when given one (so it also works
    as a decorator), else the tuple."""
    seen: dict[str, type[Encoding]] = {}
    for cls in classes:
        _check(cls)
        previous = seen.get(cls.name) or ENCODINGS.get(cls.name)
        if previous is not None and previous is not cls:
            raise ValueError(f"encoding name {cls.name!r} registered twice ({previous.__module__}."
                             f"{previous.__qualname__} and {cls.__module__}.{cls.__qualname__})")
        seen[cls.name] = cls
    ENCODINGS.update(seen)
    return classes[0] if len(classes) == 1 else classes


def get_encoding(name: str) -> type[Encoding]:
    from bakery import encodings  # noqa: F401 - importing the package registers every encoding

    try:
        return ENCODINGS[name]
    except KeyError:
        raise KeyError(f"unknown encoding {name!r}; known: {', '.join(ENCODINGS)}") from None

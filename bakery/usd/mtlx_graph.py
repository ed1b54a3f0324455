"""MaterialX node graphs over images, flattened into one texture: what a surface input computes, texel by texel.

A surface input fed by arithmetic over *several* images — ``multiply(base_color_image, ao_image)``, ``mix(a, b,
mask_image)``, an ORM image split by ``separate3``/``extract`` — has no single image whose scale and bias give it
(:func:`bakery.usd.mtlx.fold_affine` covers one image under constant arithmetic). Such a graph is evaluated here on
the texel grid of its images (the largest of them; the others are resampled bilinearly, with their address modes,
at its texel centres) and stored as a texture of its own, which the capture looks up per hit like any other map.

Exact where it matters: a graph that is linear in each image (``multiply``/``mix``/``add`` of images and constants)
gives the same value as evaluating it per hit at texel centres; between texels the capture interpolates the
graph's result instead of its inputs (as any texture baker that flattens a graph does). The graph's images must
share their texture coordinates (the same ``st_transform`` — ``place2d``, ``tiledimage`` tiling — and the same
address modes) and must not be UDIM sets; anything else, and every node outside :data:`NODES`, raises
:class:`GraphError` naming the reason, which the reader reports per prim and falls back to the input's default.
A colour primvar (``geompropvalue``) cannot live in a texture: a graph multiplied by one at its root is flattened
and tinted by the primvar per hit (vertex colours over a texture), anywhere else it is reported.

Node semantics are MaterialX's standard library (``stdlib_defs.mtlx``, ``stdlib_ng.mtlx``; specification v1.39,
"Standard Nodes"); defaults of unconnected inputs come from the node definitions (the ``operand`` callback).

Pure numpy: the USD and MaterialX document sides hand in callbacks (:class:`GraphAccess`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Channels of a MaterialX type.
CHANNELS = {"float": 1, "integer": 1, "boolean": 1, "vector2": 2, "color3": 3, "vector3": 3, "color4": 4,
            "vector4": 4}
#: Outputs of the separate nodes → channel.
_SEPARATE_OUTPUTS = {"outr": 0, "outg": 1, "outb": 2, "outa": 3, "outx": 0, "outy": 1, "outz": 2, "outw": 3}
#: Image nodes (leaves) and the largest depth of a graph followed.
_IMAGES = ("image", "tiledimage")
MAX_DEPTH = 64


class GraphError(ValueError):
    """A node graph that cannot be flattened (the message says why, e.g. "a noise2d node")."""


@dataclass(frozen=True)
class GraphAccess:
    """How to read a graph's nodes (document elements or USD shader prims).

    Attributes:
        category: node → MaterialX category ("multiply", "image", …).
        node_type: node → its output's MaterialX type ("color3", "float", …).
        operand: (node, input name) → ("node", upstream, output name), ("value", v) or None; unconnected inputs
            give their authored value or their node definition's default.
        image: image node → its map entry (``texture`` index, ``wrap``, optional ``st_transform``/``udim``), read with
            colour management when the node's type is a colour, or None when the file cannot be read.
        pixels: texture index → (H, W, 4) float32 linear RGBA (row 0 = the top of the image).
        key: node → a stable identity (its path: the bindings' wrapper objects are made anew on every lookup).
    """

    category: Callable[[Any], str]
    node_type: Callable[[Any], str]
    operand: Callable[[Any, str], tuple | None]
    image: Callable[[Any], dict | None]
    pixels: Callable[[int], np.ndarray]
    key: Callable[[Any], str]


@dataclass(frozen=True)
class FlatGraph:
    """A flattened graph: ``pixels`` (H, W, C) float64 of the graph's output on its images' grid with the images'
    ``wrap`` and ``st_transform``, and ``fallback`` (C,) its value with every image at its default (where a surface
    has no texture coordinates); ``pixels`` is None when the graph reads no image (a constant, ``fallback``).
    ``tint_primvar``: the colour primvar the whole graph is multiplied by per hit (a ``multiply`` at its root with a
    ``geompropvalue``: vertex colours tinting a texture), or None."""

    pixels: np.ndarray | None
    fallback: np.ndarray
    wrap: tuple[str, str] = ("repeat", "repeat")
    st_transform: tuple | None = None
    tint_primvar: str | None = None


def _constant(value: Any) -> np.ndarray:
    """A MaterialX value (float, tuple) as a (1, 1, C) array."""
    array = np.asarray(value, dtype=np.float64).reshape(-1)
    return array.reshape(1, 1, -1)


def _wrapped(index: np.ndarray, size: int, mode: str) -> np.ndarray:
    """Texel indices under an address mode (``black`` reads the edge: resampling stays inside the image)."""
    if mode == "repeat":
        return np.mod(index, size)
    if mode == "mirror":
        period = np.mod(index, 2 * size)
        return np.where(period < size, period, 2 * size - 1 - period)
    return np.clip(index, 0, size - 1)


def resample(pixels: np.ndarray, height: int, width: int, wrap: tuple[str, str]) -> np.ndarray:
    """(h, w, C) → (height, width, C): bilinear lookups at the target texel centres, with the address modes."""
    h, w = pixels.shape[:2]
    if (h, w) == (height, width):
        return pixels
    y = (np.arange(height) + 0.5) * (h / height) - 0.5
    x = (np.arange(width) + 0.5) * (w / width) - 0.5
    y0, x0 = np.floor(y).astype(np.int64), np.floor(x).astype(np.int64)
    fy, fx = (y - y0)[:, None, None], (x - x0)[None, :, None]
    rows = [_wrapped(y0 + d, h, wrap[1]) for d in (0, 1)]
    cols = [_wrapped(x0 + d, w, wrap[0]) for d in (0, 1)]
    top = pixels[rows[0]][:, cols[0]] * (1 - fx) + pixels[rows[0]][:, cols[1]] * fx
    bottom = pixels[rows[1]][:, cols[0]] * (1 - fx) + pixels[rows[1]][:, cols[1]] * fx
    return top * (1 - fy) + bottom * fy


def _broadcast(value: np.ndarray, channels: int) -> np.ndarray:
    """A value as ``channels`` channels: a float broadcasts, colour3 → colour4 appends alpha 1, 4 → 3 drops it
    (``convert``)."""
    have = value.shape[-1]
    if have == channels:
        return value
    if have == 1:
        return np.repeat(value, channels, axis=-1)
    if channels < have:
        return value[..., :channels]
    pad = np.ones(value.shape[:-1] + (channels - have,), dtype=value.dtype)
    return np.concatenate([value, pad], axis=-1)


def _binary(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Operands of a binary node: the FA variants (colour op float) broadcast the float."""
    if a.shape[-1] != b.shape[-1] and 1 not in (a.shape[-1], b.shape[-1]):
        raise GraphError(f"operands of {a.shape[-1]} and {b.shape[-1]} channels")
    return a, b


def _safe_divide(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        out = a / b
    return np.where(np.isfinite(out), out, 0.0)


def _smoothstep(t: np.ndarray) -> np.ndarray:
    return t * t * (3.0 - 2.0 * t)


#: The nodes evaluated, by category: (input names, function of the inputs' arrays). Formulas from MaterialX's
#: stdlib (v1.39); ``mix`` = fg·mix + bg·(1 − mix), ``invert`` = amount − in, ``remap`` is linear, ``smoothstep``
#: the cubic Hermite of (in − low)/(high − low) clamped to [0, 1], ``luminance`` the dot with ``lumacoeffs`` in every
#: colour channel (alpha passes), ``ifgreater`` in1 where value1 > value2 else in2.
NODES: dict[str, tuple[tuple[str, ...], Callable[..., np.ndarray]]] = {
    "add": (("in1", "in2"), lambda a, b: np.add(*_binary(a, b))),
    "subtract": (("in1", "in2"), lambda a, b: np.subtract(*_binary(a, b))),
    "multiply": (("in1", "in2"), lambda a, b: np.multiply(*_binary(a, b))),
    "divide": (("in1", "in2"), lambda a, b: _safe_divide(*_binary(a, b))),
    "modulo": (("in1", "in2"), lambda a, b: a - b * np.floor(_safe_divide(a, b))),
    "power": (("in1", "in2"), lambda a, b: np.power(np.maximum(a, 0.0), b)),
    "max": (("in1", "in2"), lambda a, b: np.maximum(*_binary(a, b))),
    "min": (("in1", "in2"), lambda a, b: np.minimum(*_binary(a, b))),
    "mix": (("fg", "bg", "mix"), lambda fg, bg, m: fg * m + bg * (1.0 - m)),
    "clamp": (("in", "low", "high"), lambda x, lo, hi: np.minimum(np.maximum(x, lo), hi)),
    "invert": (("in", "amount"), lambda x, amount: amount - x),
    "absval": (("in",), np.abs),
    "floor": (("in",), np.floor),
    "ceil": (("in",), np.ceil),
    "sqrt": (("in",), lambda x: np.sqrt(np.maximum(x, 0.0))),
    "remap": (("in", "inlow", "inhigh", "outlow", "outhigh"),
              lambda x, il, ih, ol, oh: ol + _safe_divide(x - il, ih - il) * (oh - ol)),
    "smoothstep": (("in", "low", "high"), lambda x, lo, hi: _smoothstep(np.clip(_safe_divide(x - lo, hi - lo),
                                                                                  0.0, 1.0))),
    "dotproduct": (("in1", "in2"), lambda a, b: np.sum(a * b, axis=-1, keepdims=True)),
    "ifgreater": (("value1", "value2", "in1", "in2"), lambda v1, v2, a, b: np.where(v1 > v2, a, b)),
    "ifgreatereq": (("value1", "value2", "in1", "in2"), lambda v1, v2, a, b: np.where(v1 >= v2, a, b)),
    "dot": (("in",), lambda x: x),
}


def _luminance(x: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    y = np.sum(x[..., :3] * coefficients[..., :3], axis=-1, keepdims=True)
    return np.concatenate([np.repeat(y, 3, axis=-1), x[..., 3:]], axis=-1)


class _Evaluator:
    """One graph's evaluation: with the images' texels (``at_defaults`` False) or their defaults (True)."""

    def __init__(self, access: GraphAccess, images: dict[str, tuple[dict, Any]], shape: tuple[int, int] | None,
                 at_defaults: bool) -> None:
        self.access, self.images, self.shape, self.at_defaults = access, images, shape, at_defaults
        self.memo: dict[tuple[str, str], np.ndarray] = {}

    def node(self, node: Any, output: str, depth: int = 0) -> np.ndarray:
        key = (self.access.key(node), output)
        if key not in self.memo:
            self.memo[key] = self._evaluate(node, output, depth)
        return self.memo[key]

    def _input(self, node: Any, name: str, depth: int) -> np.ndarray:
        operand = self.access.operand(node, name)
        if operand is None:
            raise GraphError(f"{self.access.category(node)} input {name} has no value")
        if operand[0] == "value":
            return _constant(operand[1])
        return self.node(operand[1], operand[2] if len(operand) > 2 else "out", depth + 1)

    def _evaluate(self, node: Any, output: str, depth: int) -> np.ndarray:
        if depth > MAX_DEPTH:
            raise GraphError(f"a graph deeper than {MAX_DEPTH} nodes (a cycle?)")
        category = self.access.category(node)
        channels = CHANNELS.get(self.access.node_type(node), 0)
        if category in _IMAGES:
            return self._image(node, channels)
        if category == "constant":
            return self._input(node, "value", depth)
        if category == "convert":
            return _broadcast(self._input(node, "in", depth), channels or 1)
        if category == "extract":
            index = int(np.asarray(self._input(node, "index", depth)).reshape(-1)[0])
            source = self._input(node, "in", depth)
            if not 0 <= index < source.shape[-1]:
                raise GraphError(f"extract index {index} of a {source.shape[-1]}-channel value")
            return source[..., index:index + 1]
        if category.startswith("separate"):
            source = self._input(node, "in", depth)
            index = _SEPARATE_OUTPUTS.get(output)
            if index is None or index >= source.shape[-1]:
                raise GraphError(f"{category} output {output!r}")
            return source[..., index:index + 1]
        if category.startswith("combine"):
            parts = [self._input(node, name, depth) for name in _input_names(category)]
            shape = np.broadcast_shapes(*(p.shape[:-1] for p in parts))
            return np.concatenate([np.broadcast_to(p, shape + (p.shape[-1],)) for p in parts], axis=-1)
        if category == "luminance":
            return _luminance(self._input(node, "in", depth), self._input(node, "lumacoeffs", depth))
        if category not in NODES:
            raise GraphError(f"a {category or 'untyped'} node, which the capture does not evaluate")
        names, function = NODES[category]
        result = function(*(self._input(node, name, depth) for name in names))
        return _broadcast(result, channels) if channels and result.shape[-1] == 1 and channels > 1 else result

    def _image(self, node: Any, channels: int) -> np.ndarray:
        entry, default = self.images[self.access.key(node)]
        channels = channels or 3
        if self.at_defaults or entry is None:
            return _broadcast(_constant(default if default is not None else 0.0), channels)
        pixels = np.asarray(self.access.pixels(int(entry["texture"])), dtype=np.float64)
        scale = np.asarray(entry.get("scale", (1.0,) * 4), dtype=np.float64)
        bias = np.asarray(entry.get("bias", (0.0,) * 4), dtype=np.float64)
        pixels = pixels * scale + bias
        pixels = resample(pixels, *self.shape, entry.get("wrap", ("repeat", "repeat")))
        return pixels[..., :1] if channels == 1 else pixels[..., :channels]


def _collect_images(node: Any, access: GraphAccess, found: dict[str, tuple[dict | None, Any, Any]],
                    seen: set[str], depth: int = 0) -> None:
    """Every image node upstream of ``node`` → (its map entry, its default, the node), by node key."""
    key = access.key(node)
    if key in seen:
        return
    if depth > MAX_DEPTH:
        raise GraphError(f"a graph deeper than {MAX_DEPTH} nodes (a cycle?)")
    seen.add(key)
    category = access.category(node)
    if category in _IMAGES:
        default = access.operand(node, "default")
        found[key] = (access.image(node), default[1] if default and default[0] == "value" else None, node)
        return
    if category == "geompropvalue":
        raise GraphError("a geompropvalue (primvar) node combined with other computed values")
    for name in _input_names(category):
        operand = access.operand(node, name)
        if operand is not None and operand[0] == "node":
            _collect_images(operand[1], access, found, seen, depth + 1)


#: Inputs of the nodes :class:`_Evaluator` handles by structure rather than by a formula of :data:`NODES`.
_STRUCTURAL_INPUTS = {"constant": ("value",), "convert": ("in",), "extract": ("in", "index"),
                      "luminance": ("in", "lumacoeffs"), "separate2": ("in",), "separate3": ("in",),
                      "separate4": ("in",), "combine2": ("in1", "in2"), "combine3": ("in1", "in2", "in3"),
                      "combine4": ("in1", "in2", "in3", "in4")}


def _input_names(category: str) -> tuple[str, ...]:
    """The inputs a node of ``category`` reads (GraphError for a node the capture does not evaluate)."""
    names = NODES[category][0] if category in NODES else _STRUCTURAL_INPUTS.get(category)
    if names is None:
        raise GraphError(f"a {category or 'untyped'} node, which the capture does not evaluate")
    return names


def _primvar_tint(node: Any, output: str, access: GraphAccess) -> tuple[Any, str, str | None]:
    """(graph, output, primvar): a root ``multiply`` of a graph by a colour ``geompropvalue`` is that graph tinted per
    hit by the primvar (the capture multiplies per hit: a texture cannot hold vertex colours); else (node, output,
    None)."""
    if access.category(node) != "multiply":
        return node, output, None
    operands = [access.operand(node, "in1"), access.operand(node, "in2")]
    for this, other in (operands, operands[::-1]):
        if not (this and other and this[0] == "node" and other[0] == "node"):
            continue
        if access.category(this[1]) != "geompropvalue" or CHANNELS.get(access.node_type(this[1])) != 3:
            continue
        name = access.operand(this[1], "geomprop")
        if name and name[0] == "value" and name[1]:
            return other[1], other[2] if len(other) > 2 else "out", str(name[1])
    return node, output, None


def flatten_graph(node: Any, output: str, access: GraphAccess) -> FlatGraph:
    """The output ``output`` of ``node`` evaluated over its images' texel grid (module docstring).

    Raises GraphError when the graph has a node the capture does not evaluate, images with different texture
    coordinates or address modes, or UDIM images."""
    node, output, tint = _primvar_tint(node, output, access)
    images: dict[str, tuple[dict | None, Any, Any]] = {}
    _collect_images(node, access, images, set())
    entries = [entry for entry, _default, _node in images.values() if entry is not None]
    if any("udim" in entry for entry in entries):
        raise GraphError("a UDIM image combined with other computed values")
    transforms = {repr(entry.get("st_transform")) for entry in entries}
    wraps = {tuple(entry.get("wrap", ("repeat", "repeat"))) for entry in entries}
    if len(transforms) > 1:
        raise GraphError("images with different texture coordinates (place2d, tiling) combined")
    if len(wraps) > 1:
        raise GraphError("images with different address modes combined")
    by_id = {key: (entry, default) for key, (entry, default, _node) in images.items()}
    fallback = _Evaluator(access, by_id, None, at_defaults=True).node(node, output).reshape(-1)
    if not entries:
        return FlatGraph(pixels=None, fallback=fallback, tint_primvar=tint)
    shapes = [access.pixels(int(entry["texture"])).shape[:2] for entry in entries]
    shape = (max(s[0] for s in shapes), max(s[1] for s in shapes))
    values = _Evaluator(access, by_id, shape, at_defaults=False).node(node, output)
    pixels = np.broadcast_to(values, shape + (values.shape[-1],)).astype(np.float64)
    return FlatGraph(pixels=pixels, fallback=fallback, wrap=next(iter(wraps)),
                     st_transform=entries[0].get("st_transform"), tint_primvar=tint)

"""Hand-written SVG plots for the report (no plotting dependency; the page stays self-contained).

Every plot is an ``<svg class="plot" data-plot="NAME">`` element with axes, ticks, labelled points or lines and a
legend; values are escaped. Log axes place ticks at powers of ten (and 2·, 5· when the range is short).
"""

from __future__ import annotations

import math
from html import escape

#: Colour cycle (colour-blind safe, Okabe–Ito).
PALETTE = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#CC79A7", "#56B4E9", "#F0E442", "#000000",
           "#999999", "#8C564B", "#17BECF", "#BCBD22")

_W, _H = 640, 380
_L, _R, _T, _B = 70, 170, 30, 50  # margins: left, right (legend), top, bottom


def colour(i: int) -> str:
    return PALETTE[i % len(PALETTE)]


class _Axis:
    def __init__(self, values: list[float], log: bool, lo_px: float, hi_px: float) -> None:
        finite = [v for v in values if math.isfinite(v) and (v > 0 or not log)]
        if not finite:
            finite = [1.0]
        lo, hi = min(finite), max(finite)
        if log:
            lo, hi = 10 ** math.floor(math.log10(lo)), 10 ** math.ceil(math.log10(hi))
            if lo == hi:
                lo, hi = lo / 10, hi * 10
        else:
            if lo == hi:
                lo, hi = lo - 1.0, hi + 1.0
            pad = 0.05 * (hi - lo)
            lo, hi = (0.0 if lo >= 0 and lo - pad < 0 else lo - pad), hi + pad
        self.lo, self.hi, self.log, self.lo_px, self.hi_px = lo, hi, log, lo_px, hi_px

    def __call__(self, v: float) -> float:
        if self.log:
            v = max(v, self.lo)
            t = (math.log10(v) - math.log10(self.lo)) / (math.log10(self.hi) - math.log10(self.lo))
        else:
            t = (v - self.lo) / (self.hi - self.lo)
        return self.lo_px + t * (self.hi_px - self.lo_px)

    def ticks(self) -> list[float]:
        if self.log:
            decades = range(round(math.log10(self.lo)), round(math.log10(self.hi)) + 1)
            ticks = [10.0**d for d in decades]
            if len(ticks) <= 3:
                ticks += [m * 10.0**d for d in decades for m in (2, 5) if m * 10.0**d < self.hi]
            return sorted(ticks)
        step = 10 ** math.floor(math.log10((self.hi - self.lo) / 5))
        for m in (1, 2, 5, 10):
            if (self.hi - self.lo) / (m * step) <= 6:
                step *= m
                break
        first = math.ceil(self.lo / step) * step
        return [first + i * step for i in range(int((self.hi - first) / step) + 1)]


def _fmt(v: float) -> str:
    if v == 0:
        return "0"
    if abs(v) >= 1e4 or abs(v) < 1e-3:
        return f"{v:.0e}"
    return f"{v:g}"


def _frame(name: str, title: str, xa: _Axis, ya: _Axis, xlabel: str, ylabel: str) -> list[str]:
    parts = [
        f'<svg class="plot" data-plot="{escape(name)}" xmlns="http://www.w3.org/2000/svg" width="{_W}" height="{_H}" '
        f'viewBox="0 0 {_W} {_H}" role="img" aria-label="{escape(title)}">',
        f'<title>{escape(title)}</title>',
        f'<rect x="0" y="0" width="{_W}" height="{_H}" fill="#fff"/>',
        f'<text x="{_L}" y="18" font-size="14" font-weight="bold">{escape(title)}</text>',
    ]
    x0, x1, y0, y1 = _L, _W - _R, _H - _B, _T
    parts.append(f'<rect x="{x0}" y="{y1}" width="{x1 - x0}" height="{y0 - y1}" fill="none" stroke="#333"/>')
    for t in xa.ticks():
        if xa.lo <= t <= xa.hi:
            px = xa(t)
            parts.append(f'<line x1="{px:.1f}" y1="{y0}" x2="{px:.1f}" y2="{y1}" stroke="#ddd"/>')
            parts.append(f'<text x="{px:.1f}" y="{y0 + 15}" font-size="11" text-anchor="middle">{_fmt(t)}</text>')
    for t in ya.ticks():
        if ya.lo <= t <= ya.hi:
            py = ya(t)
            parts.append(f'<line x1="{x0}" y1="{py:.1f}" x2="{x1}" y2="{py:.1f}" stroke="#ddd"/>')
            parts.append(f'<text x="{x0 - 5}" y="{py + 4:.1f}" font-size="11" text-anchor="end">{_fmt(t)}</text>')
    parts.append(f'<text x="{(x0 + x1) / 2}" y="{_H - 12}" font-size="12" text-anchor="middle">{escape(xlabel)}</text>')
    parts.append(f'<text x="16" y="{(y0 + y1) / 2}" font-size="12" text-anchor="middle" '
                 f'transform="rotate(-90 16 {(y0 + y1) / 2})">{escape(ylabel)}</text>')
    return parts


def _legend(labels: list[str]) -> list[str]:
    parts = []
    for i, label in enumerate(labels):
        y = _T + 10 + 16 * i
        parts.append(f'<rect x="{_W - _R + 12}" y="{y - 8}" width="10" height="10" fill="{colour(i)}"/>')
        parts.append(f'<text x="{_W - _R + 27}" y="{y + 1}" font-size="11">{escape(label)}</text>')
    return parts


def scatter_plot(name: str, title: str, points: list[dict], xlabel: str, ylabel: str, xlog: bool = True,
                 ylog: bool = True) -> str:
    """Points {label, x, y, y_lo?, y_hi?}: one colour per label, vertical whiskers from y_lo to y_hi."""
    xs = [p["x"] for p in points]
    ys = [p["y"] for p in points] + [p.get("y_lo", p["y"]) for p in points] + [p.get("y_hi", p["y"]) for p in points]
    xa = _Axis(xs, xlog, _L + 10, _W - _R - 10)
    ya = _Axis(ys, ylog, _H - _B - 5, _T + 5)
    parts = _frame(name, title, xa, ya, xlabel, ylabel)
    labels = list(dict.fromkeys(p["label"] for p in points))
    for p in points:
        if not (math.isfinite(p["x"]) and math.isfinite(p["y"])):
            continue
        c = colour(labels.index(p["label"]))
        px, py = xa(p["x"]), ya(p["y"])
        if "y_lo" in p and "y_hi" in p:
            parts.append(f'<line x1="{px:.1f}" y1="{ya(p["y_lo"]):.1f}" x2="{px:.1f}" y2="{ya(p["y_hi"]):.1f}" '
                         f'stroke="{c}" stroke-width="1.5"/>')
        parts.append(f'<circle cx="{px:.1f}" cy="{py:.1f}" r="5" fill="{c}" stroke="#000" stroke-width="0.5">'
                     f'<title>{escape(p["label"])}: x={p["x"]:.4g}, y={p["y"]:.4g}</title></circle>')
        parts.append(f'<text x="{px + 7:.1f}" y="{py - 4:.1f}" font-size="9" fill="#333">{escape(p["label"])}</text>')
    parts += _legend(labels)
    parts.append("</svg>")
    return "\n".join(parts)


def line_plot(name: str, title: str, series: dict[str, list[tuple[float, float]]], xlabel: str, ylabel: str,
              xlog: bool = False, ylog: bool = True) -> str:
    """Polylines with markers, one per series {label: [(x, y), ...]}."""
    xs = [x for s in series.values() for x, _ in s]
    ys = [y for s in series.values() for _, y in s]
    xa = _Axis(xs, xlog, _L + 10, _W - _R - 10)
    ya = _Axis(ys, ylog, _H - _B - 5, _T + 5)
    parts = _frame(name, title, xa, ya, xlabel, ylabel)
    for i, (label, pts) in enumerate(series.items()):
        pts = [(x, y) for x, y in pts if math.isfinite(x) and math.isfinite(y) and (y > 0 or not ylog)]
        if not pts:
            continue
        path = " ".join(f"{xa(x):.1f},{ya(y):.1f}" for x, y in pts)
        parts.append(f'<polyline points="{path}" fill="none" stroke="{colour(i)}" stroke-width="2"/>')
        for x, y in pts:
            parts.append(f'<circle cx="{xa(x):.1f}" cy="{ya(y):.1f}" r="3" fill="{colour(i)}">'
                         f'<title>{escape(label)}: {x:.4g}, {y:.4g}</title></circle>')
    parts += _legend(list(series))
    parts.append("</svg>")
    return "\n".join(parts)


def strip_plot(name: str, title: str, series: dict[str, list[float]], ylabel: str, ylog: bool = True) -> str:
    """Per-category distributions: every value as a jittered dot, with a box from the 25th to 75th percentile and
    a bar at the median."""
    labels = list(series)
    ys = [v for vs in series.values() for v in vs]
    xa = _Axis([0.0, float(max(len(labels) - 1, 1))], False, _L + 30, _W - _R - 30)
    xa.lo, xa.hi = -0.5, max(len(labels), 1) - 0.5
    ya = _Axis(ys, ylog, _H - _B - 5, _T + 5)
    parts = _frame(name, title, xa, ya, "", ylabel)
    # replace numeric x ticks with category labels
    parts = [p for p in parts if not (p.startswith("<text") and 'text-anchor="middle">' in p and f'y="{_H - _B + 15}"' in p)]
    for i, label in enumerate(labels):
        values = sorted(v for v in series[label] if math.isfinite(v) and (v > 0 or not ylog))
        c = colour(i)
        cx = xa(i)
        parts.append(f'<text x="{cx:.1f}" y="{_H - _B + 12}" font-size="10" text-anchor="end" '
                     f'transform="rotate(-30 {cx:.1f} {_H - _B + 12})">{escape(label)}</text>')
        if not values:
            continue
        q = [values[min(len(values) - 1, int(round(f * (len(values) - 1))))] for f in (0.25, 0.5, 0.75)]
        parts.append(f'<rect x="{cx - 12:.1f}" y="{ya(q[2]):.1f}" width="24" height="{max(ya(q[0]) - ya(q[2]), 1):.1f}" '
                     f'fill="{c}" fill-opacity="0.25" stroke="{c}"/>')
        parts.append(f'<line x1="{cx - 14:.1f}" y1="{ya(q[1]):.1f}" x2="{cx + 14:.1f}" y2="{ya(q[1]):.1f}" '
                     f'stroke="{c}" stroke-width="2"/>')
        for k, v in enumerate(values[:2000]):
            jitter = ((k * 0.6180339887) % 1.0 - 0.5) * 16
            parts.append(f'<circle cx="{cx + jitter:.1f}" cy="{ya(v):.1f}" r="2" fill="{c}"/>')
    parts.append("</svg>")
    return "\n".join(parts)


def bar_plot(name: str, title: str, bars: list[tuple[str, float]], xlabel: str, log: bool = True) -> str:
    """Horizontal bars (label, value) on a (log) value axis."""
    height = max(_H, _T + _B + 22 * len(bars))
    values = [v for _, v in bars]
    xa = _Axis(values, log, 200, 600)
    parts = [f'<svg class="plot" data-plot="{escape(name)}" xmlns="http://www.w3.org/2000/svg" width="{_W}" '
             f'height="{height}" viewBox="0 0 {_W} {height}" role="img" aria-label="{escape(title)}">',
             f'<title>{escape(title)}</title>', f'<rect width="{_W}" height="{height}" fill="#fff"/>',
             f'<text x="10" y="18" font-size="14" font-weight="bold">{escape(title)}</text>']
    for t in xa.ticks():
        if xa.lo <= t <= xa.hi:
            parts.append(f'<line x1="{xa(t):.1f}" y1="{_T}" x2="{xa(t):.1f}" y2="{height - _B}" stroke="#ddd"/>')
            parts.append(f'<text x="{xa(t):.1f}" y="{height - _B + 15}" font-size="11" text-anchor="middle">{_fmt(t)}</text>')
    for i, (label, v) in enumerate(bars):
        y = _T + 4 + 22 * i
        parts.append(f'<text x="195" y="{y + 13}" font-size="11" text-anchor="end">{escape(label)}</text>')
        if math.isfinite(v) and v > 0:
            parts.append(f'<rect x="200" y="{y}" width="{max(xa(v) - 200, 1):.1f}" height="16" fill="{colour(i)}">'
                         f'<title>{escape(label)}: {v:,.0f}</title></rect>')
    parts.append(f'<text x="400" y="{height - 12}" font-size="12" text-anchor="middle">{escape(xlabel)}</text>')
    parts.append("</svg>")
    return "\n".join(parts)

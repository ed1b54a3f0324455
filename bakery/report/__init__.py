"""``bakery report``: a self-contained HTML page (inline CSS, SVG plots, base64 PNG previews; no scripts, no network)
and a JSON file describing a probe store's memory and quality. Computation goes through :mod:`bakery.api` only.

Modules: :mod:`~bakery.report.memory` (bytes against split-sum chains and SH3), :mod:`~bakery.report.quality`
(errors, negative share, quantization, per-α curves), :mod:`~bakery.report.render` (sphere previews),
:mod:`~bakery.report.svg` / :mod:`~bakery.report.png` (drawing), :mod:`~bakery.report.page` (HTML),
:mod:`~bakery.report.build` (assembly and atomic writing).
"""

from bakery.report.build import build_report, write_report

__all__ = ["build_report", "write_report"]

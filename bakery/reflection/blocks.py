"""Fixed-size probe blocks for the batched reflection fits and prefilters.

Every block holds exactly :data:`PROBE_BLOCK` captures (the last padded with black ones), so the matrix products see
the same shapes whatever the batch, and a probe's result depends on its capture alone: OpenBLAS picks its kernels —
and with them the order of the sums — by the shapes (measured: a 1-probe SH projection or SH-exponential fit differed
from a 16-probe one by 1e-6 relative, so a probe re-baked alone, or a recipe's ``batch_size``, changed the store's
bits; ``tests/encodings/test_encoding_conformance.py``). Products whose columns are independent by construction
(scipy's sparse × dense, per-probe quadratures) need no blocks.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: Probes per block (module doc); 16 is also a bake's chunk of prefiltered probes (≈ 12 MB of temporaries per probe
#: at 128²).
PROBE_BLOCK = 16


def probe_blocks(count: int, size: int = PROBE_BLOCK) -> list[slice]:
    """Slices of ≤ ``size`` consecutive probes covering ``count`` probes (pad each with :func:`padded_block`)."""
    return [slice(start, min(start + size, count)) for start in range(0, count, size)]


def in_column_blocks(linear_map: Callable[[np.ndarray], np.ndarray], columns: np.ndarray,
                     width: int = 3 * PROBE_BLOCK) -> np.ndarray:
    """``linear_map(columns)`` for a map that acts on each column of the last axis alone (a projection, a basis
    product: (…, Q) → (…′, Q)), computed on blocks of exactly ``width`` columns, the last padded with zeros, so
    that every matrix product inside has the same shapes whatever Q (:data:`PROBE_BLOCK`). → (…′, Q)."""
    q = columns.shape[-1]
    out = []
    for start in range(0, q, width):
        block = columns[..., start : start + width]
        if block.shape[-1] < width:
            pad = np.zeros((*block.shape[:-1], width - block.shape[-1]), block.dtype)
            block = np.concatenate([block, pad], axis=-1)
        out.append(linear_map(block)[..., : min(width, q - start)])
    return out[0] if len(out) == 1 else np.concatenate(out, axis=-1)


def padded_block(array: np.ndarray, block: slice, size: int = PROBE_BLOCK) -> np.ndarray:
    """``array[block]`` (B, …) padded with zeros (black captures) to (``size``, …) along the probe axis."""
    part = array[block]
    if part.shape[0] == size:
        return part
    return np.concatenate([part, np.zeros((size - part.shape[0], *part.shape[1:]), part.dtype)])

"""The single writer: what a store holds for merged results (``schemas/store-v1.md``), written atomically.

Encodings are recorded with the parameters their ``finalize`` returned (:func:`bakery.pipeline.merge.
finalize_encodings`), so every stored encoding evaluates from the store alone.
"""

from __future__ import annotations

import json
import os
import time
from typing import Any

import numpy as np

import bakery
from bakery.conventions import convention_attributes
from bakery.encodings import Encoding
from bakery.pipeline.encode import EncodedBatch
from bakery.pipeline.settings import BakeSettings
from bakery.store.format import StoreContents


def bake_time() -> str:
    """UTC bake time; ``SOURCE_DATE_EPOCH`` (reproducible-builds convention) pins it for bit-identical stores."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    seconds = int(epoch) if epoch and epoch.isdigit() else int(time.time())
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(seconds))


def store_contents(
    merged: EncodedBatch, settings: BakeSettings, encodings: dict[str, Encoding],
    attributes: dict[str, Any] | None = None, probe_hashes: list[str] | None = None,
    history: list[dict[str, str]] | None = None, bake_ids: np.ndarray | None = None, layers: str = "",
) -> StoreContents:
    """The store for merged results (probes in ``merged.probes`` order).

    ``history`` lists earlier bakes still referenced by ``bake_ids``; this bake is appended as the last entry when
    some probe is attributed to it (bake id ``len(history)``; default: all probes).
    """
    when = bake_time()
    this_bake = {"time_utc": when, "bakery_version": bakery.__version__, "settings_hash": settings.hash(),
                 "layers": layers}
    history = list(history or [])
    # This bake enters the history only if it produced a probe: a re-bake that reuses every probe leaves the store's
    # bytes unchanged (with SOURCE_DATE_EPOCH), instead of growing the history by an entry nothing refers to.
    if bake_ids is None or np.any(np.asarray(bake_ids) == len(history)) or not history:
        history.append(this_bake)
    if bake_ids is None:
        bake_ids = np.full(len(merged.probes), len(history) - 1, dtype=np.int32)
    return StoreContents(
        attributes={
            **convention_attributes(),
            "bakery_version": bakery.__version__,
            "settings": settings.as_json(),
            "settings_hash": settings.hash(),
            "bake_time_utc": when,
            "bake_face_size": settings.face_size,
            "warnings": json.dumps([w.message for w in merged.warnings]),
            **(attributes or {}),
        },
        probe_names=[p.name for p in merged.probes],
        probe_kinds=[",".join(p.kinds) for p in merged.probes],
        probe_positions=np.array([p.position for p in merged.probes], dtype=np.float64).reshape(-1, 3),
        encodings={
            name: {
                "attributes": {
                    "encoding_type": name,
                    "encoding_version": encodings[name].version,
                    "kind": encodings[name].kind,
                    "description": encodings[name].description,
                    "settings": encodings[name].settings_json(),
                    "bytes_per_probe": encodings[name].bytes_per_probe(),
                },
                "fields": {"probe_index": merged.rows[name].astype(np.int32), **merged.encoded[name]},
                "descriptions": {"probe_index": "row -> index into /probes",
                                 **{s.name: s.description for s in encodings[name].field_specs()}},
                "shared": encodings[name].shared_tables(),
            }
            for name in merged.encoded
        },
        diagnostics=merged.diagnostics,
        probe_hashes=probe_hashes,
        probe_bake_ids=np.asarray(bake_ids, dtype=np.int32),
        history=history,
    )

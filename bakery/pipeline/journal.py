"""Checkpoint journal: finished batches survive a killed bake.

Layout: ``<store>.partial/<batch key>.pkl`` (beside the source's snapshot for workers), one pickled :class:`~bakery.pipeline.worker.BatchOutcome` per finished
batch, each written atomically (temp file + fsync + rename), so a SIGKILL at any moment leaves only whole files. A
batch key is the hash of its probes' content hashes (which include the settings and code version), so a journal
entry is reused only by a bake that would compute exactly the same batch. The journal is deleted after the store
has been written.
"""

from __future__ import annotations

import os
import pickle
import shutil
from pathlib import Path

from bakery.files import atomic_replace
from bakery.pipeline.worker import BatchOutcome


class Journal:
    def __init__(self, store_path: str | os.PathLike[str]) -> None:
        store_path = Path(store_path)
        self.directory = store_path.with_name(store_path.name + ".partial")

    def load(self, keys: set[str]) -> dict[str, BatchOutcome]:
        """Finished outcomes for the given batch keys (unreadable entries are ignored and recomputed)."""
        found: dict[str, BatchOutcome] = {}
        if not self.directory.is_dir():
            return found
        for key in keys:
            path = self.directory / f"{key}.pkl"
            if path.is_file():
                try:
                    with open(path, "rb") as handle:
                        outcome = pickle.load(handle)
                    if isinstance(outcome, BatchOutcome) and outcome.key == key:
                        found[key] = outcome
                except (OSError, pickle.UnpicklingError, EOFError, AttributeError):
                    continue
        return found

    def save(self, outcome: BatchOutcome) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        with atomic_replace(self.directory / f"{outcome.key}.pkl") as tmp, open(tmp, "wb") as handle:
            pickle.dump(outcome, handle, protocol=pickle.HIGHEST_PROTOCOL)

    def remove(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)

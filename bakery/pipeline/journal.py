"""Checkpoint journal: finished batches survive a killed bake.

Layout: ``<store>.partial/<batch key>.pkl`` (beside the source's snapshot for workers), one pickled
:class:`~bakery.pipeline.worker.BatchOutcome` per finished batch, each written atomically (temp file + fsync +
rename), so a SIGKILL at any moment leaves only whole files. A batch key is the hash of its probes' content hashes
(which include the settings and code version), so a journal entry is reused only by a bake that would compute
exactly the same batch. The journal is deleted after the store has been written. The parent's spilled fields
(``fields/``, :data:`bakery.pipeline.run.SPILL_FOLDER`) share the folder; they are not checkpoints.

Integrity: each file starts with a header line ``bakery-journal 2 <sha256 of the body>``; the body is the pickle
compressed by zlib (level 1: a fixed-layout chain is mostly zero rows — a production batch of 64 hybrid probes at
128² pickles to 156 MB and compresses to 2.2 MB in 0.24 s, 2026-12-07: a bake of 1 000 such probes wrote 2.5 GB of
checkpoints; the hall's captures are smooth, a Poly Haven capture compresses to 75–83 %). An entry whose bytes do
not match (a damaged disk, an edited file), of another journal version (version 1: uncompressed), or that cannot be
decompressed or unpickled is ignored — its batch is baked again — so a checkpoint is never reused unverified.
"""

from __future__ import annotations

import os
import pickle
import shutil
import stat
import zlib
from pathlib import Path

from bakery.files import OutputError, atomic_replace, os_error_message, sha256_bytes
from bakery.pipeline.worker import BatchOutcome

_MAGIC = b"bakery-journal 2 "
#: zlib level of the checkpoints' bodies (module doc).
_COMPRESSION_LEVEL = 1


class Journal:
    def __init__(self, store_path: str | os.PathLike[str]) -> None:
        store_path = Path(store_path)
        self.directory = store_path.with_name(store_path.name + ".partial")
        self._check_directory()

    def _check_directory(self) -> None:
        """OutputError unless the work folder is absent or a real folder of this user: workers unpickle its
        checkpoints and read its snapshot, and the bake writes into it, so a symbolic link (to a user's folder) or a
        folder another user planted is refused, never followed."""
        try:
            info = os.lstat(self.directory)
        except FileNotFoundError:
            return
        except OSError as error:
            raise OutputError(f"{self.directory}: cannot read the bake's work folder: {os_error_message(error)}"
                              ) from None
        if stat.S_ISLNK(info.st_mode) or not stat.S_ISDIR(info.st_mode):
            what = "a symbolic link" if stat.S_ISLNK(info.st_mode) else "not a folder"
            raise OutputError(f"{self.directory}: the bake's work folder is {what}; bakery uses only a real folder "
                              f"of its own there: remove it")
        if info.st_uid != os.geteuid():
            raise OutputError(f"{self.directory}: the bake's work folder belongs to another user (uid "
                              f"{info.st_uid}); bakery resumes only from its own checkpoints: remove it")

    def load(self, keys: set[str]) -> dict[str, BatchOutcome]:
        """Verified finished outcomes for the given batch keys (unverifiable entries are ignored and recomputed)."""
        found: dict[str, BatchOutcome] = {}
        if not self.directory.is_dir():
            return found
        for key in keys:
            path = self.directory / f"{key}.pkl"
            if not path.is_file():
                continue
            try:
                data = path.read_bytes()
                header, _, body = data.partition(b"\n")
                if not header.startswith(_MAGIC) or header[len(_MAGIC):].decode() != sha256_bytes(body):
                    continue
                outcome = pickle.loads(zlib.decompress(body))  # our own checkpoint, verified above
                if isinstance(outcome, BatchOutcome) and outcome.key == key:
                    found[key] = outcome
            except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ValueError, UnicodeDecodeError,
                    zlib.error):
                continue
        return found

    def save(self, outcome: BatchOutcome) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        body = zlib.compress(pickle.dumps(outcome, protocol=pickle.HIGHEST_PROTOCOL), _COMPRESSION_LEVEL)
        with atomic_replace(self.directory / f"{outcome.key}.pkl") as tmp, open(tmp, "wb") as handle:
            handle.write(_MAGIC + sha256_bytes(body).encode() + b"\n")
            handle.write(body)

    def remove(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)

"""Issue 15, audit finding 2 — a killed or terminated ``bakery export`` is recovered, and never blocks the folder.

The export stages every file beside its target, writes a journal (``.bakery-export.journal``: every staged file with
its sha256, the previous and the new manifest), renames the files and then the manifest, and removes the journal,
all under the folder's lock (``.bakery-export.lock``). The faults are injected deterministically in a real
``bakery export`` process (:data:`HARNESS`): SIGKILL or SIGTERM right after the k-th rename into the folder (k = 0:
right after the journal was written), or after the k-th file was staged (before any rename). Checked on files only
(sha256 of every file, hidden ones included), no consumer runs:

* a kill after k of n renames — none, one, half, all but the manifest, all — is completed by the next export,
  which then equals an uninterrupted export byte for byte, with no temporary, journal or lock file left;
* a kill before the commit leaves the previous export as it was, and the next export removes the dead process's
  staged files;
* SIGTERM while staging leaves the previous export byte-identical (a new folder is not created); SIGTERM while
  renaming completes the export before exiting 143; neither leaves a temporary file;
* a file a user changed after the kill (renamed already, or not yet) is still refused after the recovery, and the
  user's bytes are kept; staged files that vanished, and temporaries an older bakery left, do not block the folder.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from faultkit import ENV, cli, dead_pid, temporaries, write_env

pytestmark = pytest.mark.faults

JOURNAL = ".bakery-export.journal"
FORMAT = ("--format", "gltf")
NEW = ("--profile", "gltf")  # the export that is interrupted; the previous export used the default (babylon)

#: ``python -c HARNESS SIGNAL POINT K OUT -- bakery arguments``: the real command line, with one fault injected.
#: POINT ``rename``: the signal right after the K-th rename of a file into OUT (K = 0: right after the journal was
#: written, before any rename); ``stage``: when the format yields file K (files 0 … K−1 are staged, none renamed).
HARNESS = r"""
import os, signal, sys
sig, point, k, out = getattr(signal, sys.argv[1]), sys.argv[2], int(sys.argv[3]), os.path.abspath(sys.argv[4])
args = sys.argv[sys.argv.index("--") + 1:]
fired = []

def fire():
    if not fired:
        fired.append(True)
        os.kill(os.getpid(), sig)

if point == "rename":
    real = os.replace
    renames = []

    def replace(src, dst, *a, **kw):
        real(src, dst, *a, **kw)
        dst = os.path.abspath(dst)
        if os.path.basename(dst) == ".bakery-export.journal":
            if k == 0:
                fire()
        elif dst.startswith(out + os.sep):
            renames.append(dst)
            if len(renames) == k:
                fire()

    os.replace = replace
else:
    from bakery.export import EXPORT_FORMATS

    for cls in EXPORT_FORMATS.values():
        def build(self, context, _build=cls.build):
            for i, f in enumerate(_build(self, context)):
                if i == k:
                    fire()
                yield f
        cls.build = build

from bakery.cli import main
main(args, prog_name="bakery")
"""


def hashes(folder: Path) -> dict[str, str]:
    """sha256 of every file under ``folder`` (hidden ones too), by path relative to it."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def faulty(store: Path, out: Path, sig: str, point: str, k: int, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", HARNESS, sig, point, str(k), str(out), "--",
                           "export", str(store), "-o", str(out), *FORMAT, *extra],
                          capture_output=True, text=True, check=False, env=ENV, timeout=300)


def export(store: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    return cli("export", store, "-o", out, *FORMAT, *extra)


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """A store (one environment probe, splitsum), its previous export (``prev``, babylon profile) and what an
    uninterrupted export with the gltf profile gives over it (``after``) and into a new folder (``fresh``). Every
    folder is a sibling, so the manifests record the store the same way."""
    d = tmp_path_factory.mktemp("export_crash")
    import bakery

    bakery.bake(write_env(d / "env.exr", size=(32, 64)), d / "env.h5", encodings=("sh2", "splitsum"),
                face_size=16)
    store = d / "env.h5"
    for name, steps in (("prev", [()]), ("after", [(), NEW]), ("fresh", [NEW])):
        for extra in steps:
            result = export(store, d / name, *extra)
            assert result.returncode == 0, result.stderr
    n = len(json.loads((d / "fresh" / "bakery-export.json").read_text())["files"])
    prev, after = hashes(d / "prev"), hashes(d / "after")
    assert n > 10 and sum(prev.get(p) != h for p, h in after.items()) > n // 2  # most files change
    return {"dir": d, "store": store, "n": n, "prev": prev, "after": after, "fresh": hashes(d / "fresh")}


def _workdir(case, name: str, previous: bool) -> Path:
    work = case["dir"] / name
    if previous:
        shutil.copytree(case["dir"] / "prev", work)
    return work


def _assert_equals_a_clean_export(case, work: Path, previous: bool) -> None:
    assert hashes(work) == case["after" if previous else "fresh"]  # every byte; no temporary, journal or lock
    assert not temporaries(work)


KILLS = {"none": lambda n: 0, "one": lambda n: 1, "half": lambda n: n // 2, "all-but-manifest": lambda n: n,
         "all": lambda n: n + 1}


@pytest.mark.parametrize("when,previous", [(when, True) for when in KILLS] + [("none", False), ("half", False)],
                         ids=lambda v: v if isinstance(v, str) else ("previous" if v else "new-folder"))
def test_a_commit_killed_after_k_renames_is_completed_by_the_next_export(case, when, previous):
    work = _workdir(case, f"kill-{when}-{previous}", previous)
    k = KILLS[when](case["n"])
    killed = faulty(case["store"], work, "SIGKILL", "rename", k, *NEW)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    assert (work / JOURNAL).is_file()  # the commit was interrupted: the journal tells the next run what to finish
    staged = [p for p in temporaries(work) if ".tmp-" in p.name]
    assert len(staged) == (case["n"] + 1 - k if k <= case["n"] else 0), staged  # the files and the manifest
    if previous and 0 < k <= case["n"]:  # a mix of old and new files, the old manifest: what the audit found
        now = hashes(work)
        assert now["bakery-export.json"] == case["prev"]["bakery-export.json"]
        assert 0 < sum(now[p] == h != case["prev"].get(p) for p, h in case["after"].items()) <= k
    rerun = export(case["store"], work, *NEW)
    assert rerun.returncode == 0, rerun.stderr
    assert "completed an export that was interrupted" in rerun.stderr and "Traceback" not in rerun.stderr
    _assert_equals_a_clean_export(case, work, previous)


@pytest.mark.parametrize("previous", [True, False], ids=["previous", "new-folder"])
def test_a_kill_before_the_commit_changes_nothing_and_the_next_export_removes_its_files(case, previous):
    work = _workdir(case, f"stage-kill-{previous}", previous)
    killed = faulty(case["store"], work, "SIGKILL", "stage", 5, *NEW)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    left = temporaries(work)
    assert sorted(p.name for p in left if ".tmp-" in p.name) and not (work / JOURNAL).exists()
    assert len([p for p in left if ".tmp-" in p.name]) == 5
    if previous:  # apart from the staged files and the lock file: the previous export, byte for byte
        assert {p: h for p, h in hashes(work).items() if work / p not in left} == case["prev"]
    rerun = export(case["store"], work, *NEW)
    assert rerun.returncode == 0, rerun.stderr
    assert "removed 5 temporary file(s) of an interrupted export" in rerun.stderr, rerun.stderr
    assert "took over the lock of an export that is no longer running" in rerun.stderr
    _assert_equals_a_clean_export(case, work, previous)


@pytest.mark.parametrize("previous", [True, False], ids=["previous", "new-folder"])
def test_sigterm_while_staging_leaves_the_previous_export_unchanged(case, previous):
    work = _workdir(case, f"stage-term-{previous}", previous)
    stopped = faulty(case["store"], work, "SIGTERM", "stage", 5, *NEW)
    assert stopped.returncode == 128 + signal.SIGTERM and "Traceback" not in stopped.stderr, stopped.stderr
    if previous:
        assert hashes(work) == case["prev"]  # byte-identical: no staged file, no journal, no lock file
    else:
        assert not work.exists()  # the folder it created is gone again


@pytest.mark.parametrize("previous", [True, False], ids=["previous", "new-folder"])
def test_sigterm_while_renaming_completes_the_commit_before_exiting(case, previous):
    """Once the journal is written the commit is completed, also by the terminated process itself: no temporary
    file and no half-replaced export (a new folder is taken out again, as for any failure)."""
    work = _workdir(case, f"rename-term-{previous}", previous)
    stopped = faulty(case["store"], work, "SIGTERM", "rename", case["n"] // 2, *NEW)
    assert stopped.returncode == 128 + signal.SIGTERM and "Traceback" not in stopped.stderr, stopped.stderr
    if previous:
        _assert_equals_a_clean_export(case, work, previous)
    else:
        assert not work.exists()


def test_a_file_changed_after_the_kill_is_still_refused(case):
    """Recovery makes bakery's own files bakery's again, not a user's: a file changed after the kill — one already
    renamed, one whose staged replacement is still waiting — is foreign; the rerun refuses it and keeps its bytes."""
    work = _workdir(case, "foreign", True)
    killed = faulty(case["store"], work, "SIGKILL", "rename", case["n"] // 2, *NEW)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    now = hashes(work)
    changed = [p for p, h in case["after"].items()
               if case["prev"].get(p) not in (None, h) and p != "bakery-export.json"]
    renamed = next(p for p in changed if now[p] == case["after"][p])
    waiting = next(p for p in changed if now[p] == case["prev"][p])
    (work / renamed).write_bytes(b"my edit")
    (work / waiting).write_bytes(b"my other edit")
    refused = export(case["store"], work, *NEW)
    assert refused.returncode == 2 and "Traceback" not in refused.stderr, refused.stderr
    assert "refusing to overwrite" in refused.stderr and renamed in refused.stderr and waiting in refused.stderr
    assert (work / renamed).read_bytes() == b"my edit" and (work / waiting).read_bytes() == b"my other edit"
    assert not temporaries(work) and not (work / JOURNAL).exists()  # recovered all the same
    (work / renamed).unlink()
    (work / waiting).unlink()
    rerun = export(case["store"], work, *NEW)
    assert rerun.returncode == 0, rerun.stderr
    _assert_equals_a_clean_export(case, work, True)


def test_staged_files_that_vanished_do_not_block_the_folder(case):
    """The journal's sha256 and the previous manifest's both count as bakery's: with the staged files gone (deleted
    by hand), the mix of old and new files is still bakery's own and the next export replaces it."""
    work = _workdir(case, "vanished", True)
    killed = faulty(case["store"], work, "SIGKILL", "rename", case["n"] // 2, *NEW)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    for p in temporaries(work):
        if ".tmp-" in p.name:
            p.unlink()
    rerun = export(case["store"], work, *NEW)
    assert rerun.returncode == 0, rerun.stderr
    _assert_equals_a_clean_export(case, work, True)


def test_temporaries_of_dead_processes_beside_exported_files_are_removed_and_others_kept(case):
    """What a bakery without the journal left (the audit's 48 staged PNGs): staged files of dead processes beside
    files the export owns go; a user's file that only looks like one, and a live process's, stay."""
    work = _workdir(case, "older", True)
    pid = dead_pid()
    ours = [work / "environment" / f".specular_0_{i}.png.tmp-{pid}" for i in range(3)]
    ours.append(work / f".environment.gltf.tmp-{pid}")
    for p in ours:
        p.write_bytes(b"half")
    theirs = [work / f".notes.txt.tmp-{pid}", work / "environment" / f".specular_0_0.png.tmp-{1}"]  # pid 1 lives
    for p in theirs:
        p.write_bytes(b"keep")
    rerun = export(case["store"], work, *NEW)
    assert rerun.returncode == 0, rerun.stderr
    assert "removed 4 temporary file(s)" in rerun.stderr, rerun.stderr
    assert not any(p.exists() for p in ours) and all(p.read_bytes() == b"keep" for p in theirs)
    for p in theirs:
        p.unlink()
    _assert_equals_a_clean_export(case, work, True)


def test_one_export_into_a_folder_at_a_time(case):
    from bakery.files import FileLock

    work = _workdir(case, "locked", True)
    with FileLock(work / ".bakery-export"):  # what a running export into the folder holds
        refused = export(case["store"], work, *NEW)
        assert refused.returncode == 2 and "another export is writing this export folder" in refused.stderr, \
            refused.stderr
    assert hashes(work) == case["prev"]


def test_a_folder_moved_after_the_kill_is_recovered_where_it_is(case):
    """The journal names its files relative to the folder: recovery does not depend on where the folder was."""
    work = _workdir(case, "before-move", True)
    killed = faulty(case["store"], work, "SIGKILL", "rename", case["n"] // 2, *NEW)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    moved = work.rename(case["dir"] / "after-move")  # a sibling: the manifest records the store the same way
    rerun = export(case["store"], moved, *NEW)
    assert rerun.returncode == 0 and "completed an export that was interrupted" in rerun.stderr, rerun.stderr
    assert not work.exists()
    _assert_equals_a_clean_export(case, moved, True)

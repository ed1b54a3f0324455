"""Issue 15 case 2 — file-system failures are one-line errors (exit 2, no traceback) that change nothing: a read-only
or immutable output folder, a checkpoint folder that cannot be created, a full disk at every stage of a bake
(checkpoint pickle, scene snapshot, store, layer, commit), a read-only layer folder.

Real file systems: a small tmpfs per test, remounted read-only, made immutable (chattr +i) or filled. Mounting
needs root; elsewhere these tests skip with the reason (this machine and CI run as root)."""

from __future__ import annotations

import shutil

import pytest
from faultkit import (
    SCENE_FLAGS,
    assert_fails_cleanly,
    cli,
    fill,
    immutable,
    incli,
    remount,
    scene_text,
    snapshot,
    temporaries,
    tmpfs,
    write_env,
)

pytestmark = pytest.mark.faults


@pytest.fixture
def image(tmp_path):
    return write_env(tmp_path / "sky.exr", 3)


def _previous_store(folder, image):
    store = folder / "s.h5"
    result = incli("bake", image, "-o", store, "-e", "sh2", "--face-size", "4")
    assert result.returncode == 0, result.output
    return store


def test_read_only_output_folder(tmp_path, image):
    with tmpfs(tmp_path / "ro") as mount:
        store = _previous_store(mount, image)
        remount(mount, "ro")
        before = snapshot(mount)
        result = cli("bake", image, "-o", store, "-e", "sh2", "-e", "zh3", "--face-size", "4")
        assert_fails_cleanly(result, 2, "s.h5", "read-only file system")
        assert snapshot(mount) == before


def test_immutable_output_folder(tmp_path, image):
    with tmpfs(tmp_path / "imm") as mount:
        folder = mount / "out"
        folder.mkdir()
        store = _previous_store(folder, image)
        immutable(folder)
        before = snapshot(folder)
        result = cli("bake", image, "-o", store, "-e", "sh2", "-e", "zh3", "--face-size", "4")
        assert_fails_cleanly(result, 2, "s.h5", "not writable")
        assert snapshot(folder) == before
        immutable(folder, False)


def test_checkpoint_folder_cannot_be_created_when_there_is_work(tmp_path, image):
    store = _previous_store(tmp_path, image)
    (tmp_path / "s.h5.partial").write_text("a file where the checkpoint folder goes\n")  # mkdir fails
    before = snapshot(tmp_path)
    result = cli("bake", image, "-o", store, "-e", "sh2", "-e", "zh3", "--face-size", "4")
    assert_fails_cleanly(result, 2, "s.h5", "s.h5.partial")
    assert snapshot(tmp_path) == before


def test_layer_into_a_read_only_folder(tmp_path):
    scene = tmp_path / "scene.usda"
    scene.write_text(scene_text(2))
    with tmpfs(tmp_path / "layers") as mount:
        remount(mount, "ro")
        result = cli("bake", scene, "-o", tmp_path / "s.h5", "--layer", mount / "s.bake.usda", *SCENE_FLAGS)
        assert_fails_cleanly(result, 2, "s.bake.usda", "read-only file system")
        assert not (tmp_path / "s.h5").exists() and not temporaries(tmp_path)


#: Free bytes left on a 1 MiB tmpfs holding the previous store and layer (about 50 KB); a bake needs a lock page,
#: the checkpoint and snapshot (≈ 20 KB), the staged store (≈ 35 KB), the staged layer (≈ 16 KB) and the commit
#: record before anything is renamed. Each level runs out of space at a different stage.
FREE_LEVELS = [0, 4096, 12288, 24576, 40960, 61440, 81920]


def test_full_disk_at_every_stage(tmp_path):
    scene = tmp_path / "scene.usda"
    scene.write_text(scene_text(6))
    flags = ("-e", "sh2", "-e", "zh3", "--face-size", "8", "--samples", "1", "--bounces", "0", "-j", "1")
    clean = tmp_path / "clean"
    clean.mkdir()
    assert incli("bake", scene, "-o", clean / "s.h5", *flags).returncode == 0
    with tmpfs(tmp_path / "full", "1m") as mount:
        scene_v1 = tmp_path / "v1.usda"
        scene_v1.write_text(scene_text(6, lamp=20.0))
        assert incli("bake", scene_v1, "-o", mount / "s.h5", *flags).returncode == 0  # the previous store + layer
        previous = {p: mount.joinpath(p).read_bytes() for p in ("s.h5", "s.bake.usda")}
        failed_on = set()
        for free in FREE_LEVELS:
            shutil.rmtree(mount / "s.h5.partial", ignore_errors=True)  # each level starts the bake from scratch
            fill(mount, free)
            result = incli("bake", scene, "-o", mount / "s.h5", *flags)  # in process: the same exit paths, faster
            (mount / "filler.bin").unlink()
            assert not temporaries(mount), (free, temporaries(mount))
            if result.returncode == 0:
                assert free >= 40960, f"a bake with {free} bytes free should not have fitted"
                break
            assert_fails_cleanly(result, 2, "No space left on device")
            assert {p: mount.joinpath(p).read_bytes() for p in previous} == previous, free
            failed_on.add(_stage(result.output))
        # ENOSPC was hit at every stage: the lock, the snapshot, the checkpoint pickle, the staged store and layer
        assert {"lock", "snapshot", "checkpoint", "store", "layer"} <= failed_on, failed_on
        shutil.rmtree(mount / "s.h5.partial", ignore_errors=True)
        result = cli("bake", scene, "-o", mount / "s.h5", *flags)  # space again: the bake completes
        assert result.returncode == 0, result.stderr
        assert (mount / "s.bake.usda").read_bytes() == (clean / "s.bake.usda").read_bytes()


def _stage(message: str) -> str:
    if ".lock" in message:
        return "lock"
    if ".pkl" in message:
        return "checkpoint"
    if ".partial" in message:
        return "snapshot"
    if ".h5.tmp-" in message or ".h5.commit" in message:
        return "store"
    if ".usda" in message:
        return "layer"
    return message

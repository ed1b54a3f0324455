"""Links planted beside a store are refused, never followed: the lock file (its JSON would overwrite whatever the link
points to) and the bake's work folder ``<store>.partial`` (checkpoints would be written into, and unpickled from, the
link's target). Before: both were followed (CWE-59), the victim file replaced by the lock's JSON, and ~330 KB of
checkpoints and a scene snapshot left in the linked folder."""

from __future__ import annotations

import os

from faultkit import assert_fails_cleanly, cli, snapshot, write_env


def test_a_symlinked_lock_file_is_refused_and_its_target_untouched(tmp_path):
    env = write_env(tmp_path / "env.exr")
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    os.symlink(victim, tmp_path / "env.h5.lock")
    before = snapshot(tmp_path)
    result = cli("bake", env, "-o", tmp_path / "env.h5", "--face-size", 8, "-j", 1)
    assert_fails_cleanly(result, 2, "env.h5.lock", "symbolic link")
    assert snapshot(tmp_path) == before and (tmp_path / "env.h5.lock").is_symlink()


def test_a_symlinked_work_folder_is_refused_and_nothing_is_written_into_its_target(tmp_path):
    env = write_env(tmp_path / "env.exr")
    target = tmp_path / "user_folder"
    target.mkdir()
    (target / "notes.txt").write_text("mine\n")
    os.symlink(target, tmp_path / "env.h5.partial")
    before = snapshot(tmp_path)
    result = cli("bake", env, "-o", tmp_path / "env.h5", "--face-size", 8, "-j", 1)
    assert_fails_cleanly(result, 2, "env.h5.partial", "symbolic link")
    assert snapshot(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["env.exr", "env.h5.partial", "user_folder"]


def test_a_work_folder_that_is_a_file_is_refused(tmp_path):
    env = write_env(tmp_path / "env.exr")
    (tmp_path / "env.h5.partial").write_text("not a folder\n")
    result = cli("bake", env, "-o", tmp_path / "env.h5", "--face-size", 8, "-j", 1)
    assert_fails_cleanly(result, 2, "env.h5.partial", "not a folder")

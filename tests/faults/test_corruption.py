"""Issue 15 cases 3 and 4 — corrupt stores and operator caches are never trusted.

Stores: an encoding dataset deleted, NaN-filled, of the wrong shape, a flipped bit on disk (HDF5 fletcher32),
a per-probe checksum that no longer matches, /checksums removed. ``inspect``, ``diff``, ``report`` and ``migrate``
fail with exit 2 naming the dataset; a re-bake re-computes exactly the affected probes (never reuses them) and
writes the same bytes as a clean bake. Caches: a cached operator with a valid header but 0.1 % of its values
altered is detected by its SHA-256, rebuilt with a warning, and the bake's result is bit-identical to a clean one."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
from faultkit import assert_fails_cleanly, cli, incli, snapshot, write_env

pytestmark = pytest.mark.faults

FLAGS = ("-e", "sh2", "-e", "zh3", "--face-size", "4", "-j", "1")


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    d = tmp_path_factory.mktemp("corrupt")
    images = [write_env(d / f"env{i}.exr", i) for i in range(3)]
    assert incli("bake", *images, "-o", d / "clean.h5", *FLAGS).returncode == 0
    return d, images


def _delete(f):
    del f["encodings/zh3/zonal_l2"]


def _nan(f):
    f["encodings/sh2/radiance_sh"][1] = np.nan


def _shape(f):
    values = f["encodings/sh2/radiance_sh"][()]
    del f["encodings/sh2/radiance_sh"]
    f["encodings/sh2/radiance_sh"] = np.concatenate([values, values], axis=1)  # (P, 8, 3): SH3-sized


def _edit(f):
    f["encodings/zh3/radiance_sh"][2, 0, 0] += 1e-3  # a small, plausible-looking change


def _checksums_removed(f):
    del f["checksums"]


def _bit_flip(path):
    with h5py.File(path, "r") as f:
        offset = f["encodings/sh2/radiance_sh"].id.get_chunk_info(0).byte_offset
    data = bytearray(path.read_bytes())
    data[offset + 7] ^= 0x20
    path.write_bytes(bytes(data))


#: case → (how, dataset named in the message, probes a re-bake must re-compute)
CASES = {
    "dataset deleted": (_delete, "/encodings/zh3/zonal_l2", 3),
    "NaN-filled": (_nan, "/encodings/sh2/radiance_sh", 1),
    "wrong shape": (_shape, "/encodings/sh2/radiance_sh", 3),
    "values edited": (_edit, "/encodings/zh3/radiance_sh", 1),
    "bit flipped on disk": (_bit_flip, "/encodings/sh2/radiance_sh", 3),
    "checksums removed": (_checksums_removed, "/checksums", 3),
}


def _corrupt(d, case):
    how = CASES[case][0]
    path = d / f"{case.replace(' ', '_')}.h5"
    shutil.copy(d / "clean.h5", path)
    if how is _bit_flip:
        how(path)
    else:
        with h5py.File(path, "a") as f:
            how(f)
    return path


@pytest.mark.parametrize("case", list(CASES))
def test_corrupt_store_is_refused_by_every_reader(baked, case, tmp_path):
    d, _ = baked
    bad = _corrupt(d, case)
    dataset = CASES[case][1]
    before = bad.read_bytes()
    for args in (["inspect", bad], ["inspect", bad, "--json"], ["diff", d / "clean.h5", bad],
                 ["migrate", bad], ["migrate", bad, "-o", tmp_path / "m.h5"],
                 ["report", bad, "-o", tmp_path / "rep", "--no-previews"]):
        result = incli(*args)
        assert_fails_cleanly(result, 2, bad.name, dataset)
        assert "unchanged" not in result.output
    assert bad.read_bytes() == before and not (tmp_path / "m.h5").exists() and not (tmp_path / "rep").exists()


@pytest.mark.parametrize("case", list(CASES))
def test_rebake_recomputes_only_the_affected_probes(baked, case):
    d, images = baked
    bad = _corrupt(d, case)
    result = incli("bake", *images, "-o", bad, *FLAGS, "--json")
    assert result.returncode == 0, result.output
    summary = json.loads(result.stdout)
    recomputed = CASES[case][2]
    assert (summary["baked"], summary["reused"]) == (recomputed, 3 - recomputed)
    assert "integrity check" in result.output or "checksum" in result.output
    assert incli("inspect", bad).returncode == 0
    diff = json.loads(incli("diff", d / "clean.h5", bad, "--json").output)
    assert diff["changed"] == {} and diff["unchanged"] == 3  # the corruption was not copied
    if recomputed == 3:
        assert bad.read_bytes() == (d / "clean.h5").read_bytes()


def _poison(path, fraction=1e-3, seed=0):
    """Alter ``fraction`` of a cached .npy array's values, keeping its header valid."""
    array = np.load(path)
    flat = array.reshape(-1).copy()
    rng = np.random.default_rng(seed)
    picks = rng.choice(flat.size, max(1, int(flat.size * fraction)), replace=False)
    flat[picks] = flat[picks] * np.float32(1.5) + np.float32(0.25)
    with open(path, "r+b") as handle:
        np.save(handle, flat.reshape(array.shape))


def test_poisoned_operator_cache_is_detected_and_rebuilt(tmp_path):
    image = write_env(tmp_path / "sky.exr", 5)
    cache = tmp_path / "cache"
    env = {"BAKERY_CACHE_DIR": str(cache)}
    recipe = tmp_path / "small.toml"  # a small SH-exponential design: small cached operators, fast to rebuild
    recipe.write_text('name = "small"\n[targets]\nreflection = ["shexp"]\nirradiance = []\n'
                      '[encoding_settings.shexp]\nn_normals = 8\nn_views = 8\nn_alphas = 2\nfit_face_size = 8\n')
    flags = ("--recipe", recipe, "--face-size", "8", "-j", "1", "--no-reference")
    assert cli("bake", image, "-o", tmp_path / "clean.h5", *flags, env=env).returncode == 0
    files = sorted(cache.glob("*.npy"))
    assert len(files) >= 2  # the DFG table and the SH-exponential operator blocks
    for path in files:
        _poison(path)
    before = snapshot(cache)
    result = cli("bake", image, "-o", tmp_path / "again.h5", *flags, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stderr.count("does not match its SHA-256") >= len(files), result.stderr
    assert (tmp_path / "again.h5").read_bytes() == (tmp_path / "clean.h5").read_bytes()
    assert snapshot(cache) != before and sorted(p.name for p in cache.glob("*.npy")) == [p.name for p in files]


def test_damaged_checkpoint_is_recomputed_not_reused(tmp_path):
    from bakery.pipeline.journal import Journal
    from bakery.pipeline.worker import BatchOutcome

    journal = Journal(tmp_path / "s.h5")
    journal.save(BatchOutcome("k1", None, {"/a": "failed"}))
    journal.save(BatchOutcome("k2", None, {"/b": "failed"}))
    assert set(journal.load({"k1", "k2"})) == {"k1", "k2"}
    path = journal.directory / "k1.pkl"
    data = bytearray(path.read_bytes())
    data[-5] ^= 0x01  # one flipped bit in the pickle, header intact
    path.write_bytes(bytes(data))
    (journal.directory / "k2.pkl").write_bytes(b"bakery-journal 2 " + b"0" * 64 + b"\n" + b"garbage")
    assert journal.load({"k1", "k2"}) == {}


def test_a_checkpoint_is_compressed_and_one_of_another_journal_version_is_recomputed(tmp_path):
    """A checkpoint's body is the zlib-compressed pickle (a chain's zero rows cost nothing on disk); a verified body
    that is not zlib (version 1, uncompressed) or of another version is baked again, never misread."""
    import hashlib
    import pickle

    from bakery.pipeline.encode import EncodedBatch
    from bakery.pipeline.journal import Journal
    from bakery.pipeline.worker import BatchOutcome
    from bakery.probe import Probe

    levels = np.zeros((16, 6, 64, 64, 3), dtype=np.float16)
    levels[3] = 1.5
    batch = EncodedBatch([Probe(f"/p{i}", ("reflection",), (0.0, 0.0, 0.0)) for i in range(16)],
                         {"e": {"level": levels}}, {"e": np.arange(16)}, {})
    journal = Journal(tmp_path / "s.h5")
    journal.save(BatchOutcome("k1", batch))
    path = journal.directory / "k1.pkl"
    assert path.stat().st_size < levels.nbytes / 100
    loaded = journal.load({"k1"})["k1"].result.encoded["e"]["level"]
    np.testing.assert_array_equal(loaded.view(np.uint16), levels.view(np.uint16))
    body = pickle.dumps(BatchOutcome("k1", batch))  # a version-1 entry: uncompressed, its header valid
    for magic in (b"bakery-journal 1 ", b"bakery-journal 2 "):
        path.write_bytes(magic + hashlib.sha256(body).hexdigest().encode() + b"\n" + body)
        assert journal.load({"k1"}) == {}


def _header_byte_flipped(path):
    data = bytearray(path.read_bytes())
    data[60] ^= 0x01  # inside the root group's object header (superblock v2/v3: 48 bytes, then the header)
    path.write_bytes(bytes(data))


def _tail_zeroed(path):
    data = bytearray(path.read_bytes())
    data[-4096:] = bytes(4096)  # the metadata HDF5 writes last (object headers, the heap of attribute names)
    path.write_bytes(bytes(data))


#: damage to HDF5's own metadata, which h5py reports as KeyError or RuntimeError ("incorrect metadata checksum"),
#: not as the OSError of a truncated file
METADATA_DAMAGE = {"root header byte flipped": _header_byte_flipped, "tail zeroed": _tail_zeroed}


@pytest.mark.parametrize("case", list(METADATA_DAMAGE))
def test_damaged_hdf5_metadata_fails_cleanly_and_force_replaces_it(baked, case, tmp_path):
    d, images = baked
    bad = tmp_path / f"{case.replace(' ', '_')}.h5"
    shutil.copy(d / "clean.h5", bad)
    METADATA_DAMAGE[case](bad)
    before = bad.read_bytes()
    for args in (["inspect", bad], ["diff", d / "clean.h5", bad], ["migrate", bad],
                 ["report", bad, "-o", tmp_path / "rep", "--no-previews"]):
        assert_fails_cleanly(incli(*args), 2, bad.name, "corrupt")
    _refused = incli("bake", *images, "-o", bad, *FLAGS)
    assert_fails_cleanly(_refused, 2, bad.name, "not a readable HDF5 file", "--force")
    assert bad.read_bytes() == before and not (tmp_path / "rep").exists()
    replaced = incli("bake", *images, "-o", bad, *FLAGS, "--force", "--json")
    assert replaced.returncode == 0, replaced.output
    assert json.loads(replaced.stdout)["baked"] == 3  # nothing read from the damaged file
    assert json.loads(incli("diff", d / "clean.h5", bad, "--json").output)["unchanged"] == 3

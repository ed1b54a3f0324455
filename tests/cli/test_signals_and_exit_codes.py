"""Ctrl-C, SIGTERM and bad input on the command line: exit 130 / 143 with one line saying what was kept, exit 2 for
bad input, never a traceback, and the previous outputs byte-identical (docs/reliability.md, "Killed runs leave
nothing half-done").

The interrupts are not timed: a ``python -c`` driver (:data:`DRIVER`) runs the command line in its own process group
(as a shell runs a foreground job) with a hook that sends the signal at a precise point — while pxr loads, right
after a pool worker is spawned, after the first checkpoint, in a calibration's first bake, … — the way a terminal
sends Ctrl-C: SIGINT to the whole group, workers included. Before the fixes:

* a Ctrl-C while pxr loaded was turned into a warning by OpenUSD's script-module loader, and the bake went on and
  replaced the store and the layer (exit 0);
* pool workers had SIGINT at its default until their initializer ran, ≈ 1 s after the spawn: a Ctrl-C then killed
  them with tracebacks;
* a Ctrl-C during the imports or in ``export`` / ``farm calibrate`` printed click's ``Aborted!`` and exited 1;
* SIGTERM ended a bake silently, and killed ``farm calibrate`` leaving its temporary bakes (MBs) in /tmp.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "faults"))  # the fault suite's helpers

from faultkit import ENV, alive, cli, incli, scene_text, wait_for, write_env  # noqa: E402

FLAGS = ["-e", "sh2", "--face-size", "8", "--samples", "1", "--bounces", "0", "--no-reference"]

#: Runs ``bakery ARGS`` in this process after installing the hook named by argv[1]. SIGINT goes to the process group
#: (this driver leads its own), other signals to this process; the sleep is where the handler runs (or, where the
#: signal is held, where it is recorded). ``RECORD`` (environment) collects "pid shielded" of every spawned worker.
DRIVER = r"""
import os, signal, sys, time

hook, args = sys.argv[1], sys.argv[2:]
record = os.environ.get("RECORD")


def send(number=signal.SIGINT):
    if number == signal.SIGINT:
        os.killpg(0, number)  # Ctrl-C: the terminal signals the whole foreground process group
    else:
        os.kill(os.getpid(), number)
    time.sleep(0.5)


def shielded(pid):
    # SIGINT blocked or ignored in the (just spawned) worker: a Ctrl-C cannot reach it before its initializer ran
    fields = dict(line.split(":", 1) for line in open(f"/proc/{pid}/status"))
    bit = 1 << (signal.SIGINT - 1)
    return bool((int(fields["SigBlk"], 16) | int(fields["SigIgn"], 16)) & bit)


class Finder:  # a signal when a module is first imported
    def __init__(self, name):
        self.name = name

    def find_spec(self, name, path=None, target=None):
        if name == self.name:
            sys.meta_path.remove(self)
            send()
        return None


if hook == "import":  # while the command line loads
    sys.meta_path.insert(0, Finder("click"))
elif hook == "pxr":  # while pxr loads: pxr.Pcp is imported by OpenUSD's own loader (C++), for pxr.Usd
    sys.meta_path.insert(0, Finder("pxr.Pcp"))
elif hook == "spawn":
    import multiprocessing.context

    start = multiprocessing.context.SpawnProcess.start
    sent = []

    def spawn_then_ctrl_c(self):
        start(self)
        with open(record, "a") as handle:
            handle.write(f"{self.pid} {int(shielded(self.pid))}\n")
        if not sent:  # right after the first worker was spawned: it is starting Python
            sent.append(True)
            send()

    multiprocessing.context.SpawnProcess.start = spawn_then_ctrl_c
elif hook == "group":  # in the command group's callback, before the command runs
    import bakery.allocator

    bakery.allocator.tune_allocator = lambda: send()
elif hook == "export":
    import bakery.export

    bakery.export.export_store = lambda *a, **k: send()
elif hook in ("calibrate-int", "calibrate-term"):  # in the calibration's first bake (its hall is generated)
    import bakery.farm.calibrate

    number = signal.SIGINT if hook == "calibrate-int" else signal.SIGTERM
    bakery.farm.calibrate._bake = lambda *a, **k: send(number)
elif hook == "checkpoint-term":  # SIGTERM right after the first batch was checkpointed
    import bakery.pipeline.journal

    save = bakery.pipeline.journal.Journal.save

    def save_then_sigterm(self, outcome):
        save(self, outcome)
        send(signal.SIGTERM)

    bakery.pipeline.journal.Journal.save = save_then_sigterm

from bakery.cli import main

main(args=args, prog_name="bakery")
"""


def drive(hook: str, *args, env: dict | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    """``bakery ARGS`` with ``hook``, in a new session (its own process group: the SIGINT reaches only it)."""
    return subprocess.run([sys.executable, "-c", DRIVER, hook, *map(str, args)], capture_output=True, text=True,
                          env={**ENV, **(env or {})}, timeout=timeout, start_new_session=True)


def sha256(*paths: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}


def assert_stopped(result: subprocess.CompletedProcess, code: int, *needles: str) -> str:
    """Exit ``code``, exactly one ``interrupted:`` (130) or ``terminated:`` (143) line naming the needles, no
    traceback, no "Aborted!", no warning of pxr's loader. Returns that line."""
    word = "interrupted:" if code == 130 else "terminated:"
    err = result.stderr
    assert result.returncode == code, (result.returncode, err[-3000:])
    for bad in ("Traceback", "KeyboardInterrupt", "Aborted!", "Error loading", "_LoadLibModules"):
        assert bad not in err, (bad, err[-3000:])
    lines = [line for line in err.splitlines() if line.startswith(word)]
    assert len(lines) == 1, err[-3000:]
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """A 6-probe scene in 3 batches and another version of it (another dome: every probe re-bakes)."""
    d = tmp_path_factory.mktemp("signals")
    (d / "batches.toml").write_text('name = "batches"\n[targets]\nirradiance = ["sh2"]\n[pipeline]\nbatch_size = 2\n')
    (d / "scene.usda").write_text(scene_text(6, spacing=0.5))
    (d / "old.usda").write_text(scene_text(6, spacing=0.5, dome=0.8))
    return d


def previous_outputs(scenes: Path, name: str) -> tuple[Path, Path, dict[str, str]]:
    """A folder holding the store and layer of the other version of the scene: what a stopped bake must keep."""
    work = scenes / name
    work.mkdir()
    result = incli("bake", scenes / "old.usda", "-o", work / "s.h5", *FLAGS, "-j", "1")
    assert result.returncode == 0, result.output
    store, layer = work / "s.h5", work / "s.bake.usda"
    return store, layer, sha256(store, layer)


# ------------------------------------------------------------------------------------------------ Ctrl-C in bakes
def test_ctrl_c_while_pxr_loads_stops_the_bake(scenes):
    """The audit's HIGH finding: Ctrl-C ≈ 1 s into a scene bake was lost in pxr's loader (exit 0, outputs replaced,
    tracebacks of workers still importing). Now: held while pxr loads, then the bake stops."""
    store, layer, before = previous_outputs(scenes, "pxr")
    result = drive("pxr", "bake", scenes / "scene.usda", "-o", store, *FLAGS, "-j", "2", "--no-resume")
    assert_stopped(result, 130, str(store), "the previous store and layer are unchanged")
    assert sha256(store, layer) == before


def test_ctrl_c_right_after_a_worker_is_spawned(scenes, tmp_path):
    """Every worker starts with SIGINT blocked (then ignored by its initializer), so the Ctrl-C that reaches the
    whole group while it starts Python does not kill it with a traceback; the parent holds the Ctrl-C until its
    workers are started, then stops the bake, and no worker is left."""
    store, layer, before = previous_outputs(scenes, "spawn")
    record = tmp_path / "spawned.txt"
    result = drive("spawn", "bake", scenes / "scene.usda", "-o", store, *FLAGS, "-j", "2", "--no-resume",
                   env={"RECORD": str(record)})
    assert_stopped(result, 130, str(store), "the previous store and layer are unchanged")
    assert sha256(store, layer) == before
    spawned = [line.split() for line in record.read_text().splitlines()]
    assert spawned and all(flag == "1" for _, flag in spawned), spawned  # SIGINT blocked or ignored from the start
    pids = [int(pid) for pid, _ in spawned]
    assert wait_for(lambda: not alive(pids), timeout=10), f"workers still running: {alive(pids)}"


def test_a_rebuilt_pool_starts_its_workers_shielded_too(monkeypatch):
    """A worker that dies breaks the pool; its replacement's workers start shielded from Ctrl-C like the first."""
    import multiprocessing.context

    from bakery.pipeline.executors import ProcessExecutor

    status: list[tuple[int, bool]] = []
    start = multiprocessing.context.SpawnProcess.start

    def recording_start(self):  # noqa: ANN001, ANN202
        start(self)
        fields = dict(line.split(":", 1) for line in Path(f"/proc/{self.pid}/status").read_text().splitlines())
        bit = 1 << (signal.SIGINT - 1)
        status.append((self.pid, bool((int(fields["SigBlk"], 16) | int(fields["SigIgn"], 16)) & bit)))

    monkeypatch.setattr(multiprocessing.context.SpawnProcess, "start", recording_start)
    executor = ProcessExecutor(1)
    try:
        executor.start()
        pool = executor._pool
        os.kill(status[0][0], signal.SIGKILL)
        assert wait_for(lambda: pool._broken, timeout=30)
        # a stand-in batch (fails in the worker: it is not a BatchTask), given to the broken pool: a new pool
        outcomes = list(executor.run([SimpleNamespace(key="k", probes=[])]))
    finally:
        executor.close()
    assert len(outcomes) == 1 and outcomes[0].result is None
    assert len(status) == 2 and all(shielded for _, shielded in status), status
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # this process's Ctrl-C is restored
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())


# --------------------------------------------------------------------------------- Ctrl-C anywhere on the command line
@pytest.mark.parametrize("hook,command,needle", [
    ("import", ["bake", "{scene}", "-o", "{out}"], "bakery was stopped while it started; nothing was written"),
    ("group", ["bake", "{scene}", "-o", "{out}"], "bakery bake was stopped before it finished"),
    ("export", ["export", "{out}", "-o", "{tmp}/exported", "--format", "ktx2"], "bakery export was stopped"),
    ("calibrate-int", ["farm", "calibrate", "-o", "{tmp}/c.json"], "c.json: not written"),
], ids=["imports", "group", "export", "calibrate"])
def test_ctrl_c_anywhere_exits_130_in_one_line(scenes, tmp_path, hook, command, needle):
    """Before: click's ``Aborted!`` and exit 1 (a traceback during the imports)."""
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    args = [a.format(scene=scenes / "scene.usda", out=tmp_path / "s.h5", tmp=tmp_path) for a in command]
    result = drive(hook, *args, env={"TMPDIR": str(temporary)})
    assert_stopped(result, 130, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tmp"]  # nothing written
    assert not any(temporary.iterdir())  # calibrate: its temporary bakes removed


# ------------------------------------------------------------------------------------------------------------ SIGTERM
def test_sigterm_ends_a_bake_with_one_line_and_the_next_bake_resumes(scenes):
    store, layer, before = previous_outputs(scenes, "sigterm")
    args = ["bake", scenes / "scene.usda", "-o", store, *FLAGS, "--recipe", scenes / "batches.toml", "-j", "1"]
    result = drive("checkpoint-term", *args)
    assert_stopped(result, 143, str(store), "the previous store and layer are unchanged",
                   f"the finished batches are kept in {store}.partial and the next bake resumes from them")
    assert sha256(store, layer) == before
    again = cli(*args)
    assert again.returncode == 0, again.stderr
    assert "1 batches resumed from checkpoints" in again.stderr, again.stderr


def test_sigterm_of_calibrate_removes_its_temporary_bakes(tmp_path):
    """Before: killed by the signal (exit -15), leaving the generated hall and its bakes (up to 18 MB) in /tmp."""
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    output = tmp_path / "c.json"
    result = drive("calibrate-term", "farm", "calibrate", "-o", output, env={"TMPDIR": str(temporary)})
    assert_stopped(result, 143, "c.json: not written", "temporary bakes were removed")
    assert not any(temporary.iterdir()) and not output.exists()


def test_calibrate_refuses_a_missing_folder_before_creating_anything(tmp_path):
    """Before: calibrate created the folder (and started a minute of measurements) before its output check."""
    result = cli("farm", "calibrate", "-o", tmp_path / "nod" / "c.json")
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert "the calibration folder" in result.stderr and "does not exist" in result.stderr, result.stderr
    assert not (tmp_path / "nod").exists()


# ------------------------------------------------------------------------------------------------ bad input: exit 2/3
@pytest.mark.parametrize("case,needle", [("missing", "scene not found"), ("folder", "is a directory"),
                                         ("image", "not a USD scene"), ("store", "not a USD scene")])
def test_check_of_what_is_not_a_scene_is_bad_input(tmp_path, case, needle):
    """Before: ``error /: nope.usda: scene not found`` on stdout and exit 5, as if a scene had been checked."""
    path = {"missing": tmp_path / "nope.usda", "folder": tmp_path, "image": write_env(tmp_path / "sky.exr"),
            "store": tmp_path / "s.h5"}[case]
    if case == "store":
        path.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(64))
    result = cli("check", path)
    assert result.returncode == 2 and "Traceback" not in result.stderr, (result.returncode, result.stderr)
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0] and path.name in lines[0], lines


def test_check_still_exits_5_for_a_scene_with_errors(tmp_path):
    scene = tmp_path / "bad.usda"
    scene.write_text(scene_text(1).replace("BakeryIrradianceProbe", "BakeryMysteryProbe"))
    result = cli("check", scene)
    assert result.returncode == 5 and "Traceback" not in result.stderr, (result.returncode, result.stderr)


@pytest.mark.parametrize("value", ["inf", "-inf", "nan"])
def test_time_must_be_a_finite_number(scenes, tmp_path, value):
    """Before: ``--time inf`` was accepted while ``--time nan`` was refused."""
    result = incli("bake", scenes / "scene.usda", "-o", tmp_path / "s.h5", *FLAGS, "--time", value)
    assert result.returncode == 3 and not result.traceback, result
    assert f"capture time must be a finite number (a USD time code), got {float(value)!r}" in result.output
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("shard", [[], ["--shard", "1/2"]], ids=["bake", "shard"])
def test_scheduler_and_dask_local_exclude_each_other(scenes, tmp_path, shard):
    """Before: accepted silently (the scheduler won)."""
    started = time.monotonic()
    result = incli("bake", scenes / "scene.usda", "-o", tmp_path / "s.h5", *FLAGS, *shard,
                   "--scheduler", "tcp://127.0.0.1:9", "--dask-local")
    assert result.returncode == 2 and not result.traceback, result
    assert "--scheduler and --dask-local exclude each other" in result.output
    assert not any(tmp_path.iterdir()) and time.monotonic() - started < 30

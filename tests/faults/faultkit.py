"""Helpers of the fault-injection suite (``tests/faults``, marker ``faults``): run the command line (in process for
speed, or as a real subprocess where signals, locks and exit paths matter), snapshot folders byte for byte, make
small real inputs, and mount small file systems (tmpfs) that can be made read-only, immutable or full.

Mounting needs root (CAP_SYS_ADMIN); elsewhere those tests skip with the reason."""

from __future__ import annotations

import os
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

ENV = {**os.environ, "SOURCE_DATE_EPOCH": "1700000000"}
ENV.pop("BAKERY_FAULT", None)


def cli(*args, env: dict | None = None, timeout: float = 300, cwd=None) -> subprocess.CompletedProcess:
    """``python -m bakery.cli ARGS`` as a user runs it."""
    return subprocess.run([sys.executable, "-m", "bakery.cli", *map(str, args)], capture_output=True, text=True,
                          check=False, env={**ENV, **(env or {})}, timeout=timeout, cwd=cwd)


def popen(*args, env: dict | None = None, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "bakery.cli", *map(str, args)], env={**ENV, **(env or {})},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


class Result:
    """What a command did: exit code, stdout + stderr, and whether it escaped as a Python exception."""

    def __init__(self, code: int, output: str, traceback: bool, stdout: str = "") -> None:
        self.returncode, self.output, self.traceback, self.stdout = code, output, traceback, stdout

    def __repr__(self) -> str:
        return f"Result({self.returncode}, {self.output[-2000:]!r})"


def incli(*args) -> Result:
    """The command line in this process (click's runner): the same code path, without interpreter start-up."""
    from click.testing import CliRunner

    from bakery.cli import main

    os.environ["SOURCE_DATE_EPOCH"] = "1700000000"
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=True)
    escaped = result.exception is not None and not isinstance(result.exception, SystemExit)
    return Result(result.exit_code, result.output, escaped, result.stdout)


def assert_fails_cleanly(result, code: int, *needles: str) -> None:
    """Exit ``code``, no traceback, every needle in the output (file names, reasons)."""
    text = result.output if isinstance(result, Result) else result.stdout + result.stderr
    traceback = result.traceback if isinstance(result, Result) else "Traceback" in result.stderr
    assert result.returncode == code, (result.returncode, text[-3000:])
    assert not traceback and "Traceback" not in text, text[-3000:]
    for needle in needles:
        assert needle in text, (needle, text[-3000:])


def snapshot(*folders: Path) -> dict[str, bytes]:
    """Every file under the folders (relative path → bytes), ignoring caches."""
    out = {}
    for folder in folders:
        for path in sorted(Path(folder).rglob("*")):
            if path.is_file() and "__pycache__" not in path.parts:
                out[str(path)] = path.read_bytes()
    return out


def temporaries(*folders: Path) -> list[Path]:
    """Temporary files (``*.tmp-*``) and lock files left under the folders."""
    return [p for folder in folders for p in Path(folder).rglob("*") if ".tmp-" in p.name or p.name.endswith(".lock")]


def write_env(path: Path, seed: int = 0, size=(16, 32), scale: float = 1.0) -> Path:
    """A small equirect OpenEXR environment of log-normal radiance."""
    from bakery.environment.io import write_exr

    pixels = np.random.default_rng(seed).lognormal(0.0, 1.0, (*size, 3)).astype(np.float32) * np.float32(scale)
    write_exr(path, pixels.astype(np.float32))
    return path


def scene_text(probes: int = 3, lamp: float = 50.0, spacing: float = 1.0, extra: str = "", dome: float = 0.5) -> str:
    """A ground plane, a dome, one sphere lamp and ``probes`` irradiance probes in a row."""
    from usd_scenes import header, material, plane_mesh, probe

    row = "".join(probe(f"P{i}", (i * spacing, 1.0, 0.0)) for i in range(probes))
    return (header(extra=extra) + material("Grey") + plane_mesh("Ground", 50.0, "/Grey") + f"""
def DomeLight "Sky"
{{
    float inputs:intensity = {dome}
}}
def SphereLight "Lamp"
{{
    float inputs:intensity = {lamp}
    float inputs:radius = 0.1
    double3 xformOp:translate = (0, 1.5, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
""" + row)


SCENE_FLAGS = ("-e", "sh2", "--face-size", "4", "--samples", "1", "--bounces", "0")


def _run(*command: str) -> subprocess.CompletedProcess:
    return subprocess.run(list(command), capture_output=True, text=True, check=False)


@contextmanager
def tmpfs(path: Path, size: str = "1m"):
    """A fresh tmpfs of ``size`` mounted at ``path`` (skips the test where mounting is not allowed)."""
    path.mkdir(parents=True, exist_ok=True)
    mounted = _run("mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs", str(path))
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({mounted.stderr.strip() or 'mount failed'}); the read-only and "
                    "full file-system cases need root (CAP_SYS_ADMIN)")
    try:
        yield path
    finally:
        _run("chattr", "-R", "-i", str(path))
        _run("umount", "-l", str(path))


def remount(path: Path, mode: str) -> None:
    result = _run("mount", "-o", f"remount,{mode}", str(path))
    assert result.returncode == 0, result.stderr


def immutable(path: Path, on: bool = True) -> None:
    result = _run("chattr", "+i" if on else "-i", str(path))
    if result.returncode != 0:
        pytest.skip(f"chattr is not supported here: {result.stderr.strip()}")


def fill(folder: Path, leave_bytes: int) -> None:
    """Fill the file system of ``folder`` so that about ``leave_bytes`` stay free (4 KiB pages)."""
    filler = folder / "filler.bin"
    with open(filler, "ab") as handle:
        while True:
            free = os.statvfs(folder).f_bavail * os.statvfs(folder).f_frsize
            if free <= leave_bytes:
                break
            step = min(free - leave_bytes, 1 << 20)
            try:
                handle.write(b"\0" * max(step, 4096))
                handle.flush()
            except OSError:
                break


def dead_pid() -> int:
    """The pid of a process that has exited."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def children(pid: int) -> list[int]:
    """Live descendant pids of ``pid``."""
    import psutil

    try:
        return [c.pid for c in psutil.Process(pid).children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


def pool_workers(pid: int) -> list[int]:
    """Descendants of ``pid`` that are multiprocessing (spawn) workers, not helper processes."""
    import psutil

    out = []
    for child in children(pid):
        try:
            if "spawn_main" in " ".join(psutil.Process(child).cmdline()):
                out.append(child)
        except psutil.NoSuchProcess:
            continue
    return out


def alive(pids: list[int]) -> list[int]:
    import psutil

    out = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                out.append(pid)
        except psutil.NoSuchProcess:
            continue
    return out


def wait_for(condition, timeout: float = 60.0, interval: float = 0.02) -> bool:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(interval)
    return False

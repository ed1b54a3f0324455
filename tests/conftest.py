import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("ci", derandomize=True, max_examples=40, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI") else "dev")

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    if not SHARED.is_dir():
        pytest.skip("../shared/data is not present")
    return SHARED


def random_positive_radiance_sh(rng: np.random.Generator, lights: int = 4, max_band: int = 2) -> np.ndarray:
    """Radiance SH (1, K, 3) of a positive function: a few coloured deltas plus a coloured ambient term."""
    from bakery.sh.basis import evaluate_sh_basis

    directions = rng.normal(size=(lights, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    colours = rng.uniform(0.0, 1.0, size=(lights, 3)) * rng.lognormal(0.0, 2.0, size=(lights, 1))
    sh = evaluate_sh_basis(directions, max_band).T @ colours  # Σ_i c_i Y(d_i)
    ambient = rng.uniform(0.0, 0.5, size=3)
    sh[0] += ambient * 2.0 * np.sqrt(np.pi)
    return sh[None]


# ------------------------------------------------------------------ tests/bench: the pytest-benchmark suite
# (here, not in tests/bench/conftest.py: the subfolders' conftests are imported as one module name, `conftest`)
MEASURED_KEY = pytest.StashKey[list]()


@pytest.fixture
def measured(request) -> list[dict]:  # noqa: ANN001
    """Where a benchmark appends {name, group, median_s, probes, store_bytes, peak_alloc_mb, …} for the summary."""
    return request.config.stash.setdefault(MEASURED_KEY, [])


def pytest_terminal_summary(terminalreporter, exitstatus, config):  # noqa: ANN001, ARG001
    measured = config.stash.get(MEASURED_KEY, [])
    if not measured:
        return
    write = terminalreporter.write_line
    terminalreporter.section("bakery benchmarks: per probe (medians of the timed rounds)")
    write(f"{'benchmark':<54} {'probes':>6} {'ms/probe':>9} {'× best':>7} {'bytes/probe':>12} {'store B':>9} "
          f"{'traced peak MB':>14}")
    for group in dict.fromkeys(m["group"] for m in measured):
        rows = [m for m in measured if m["group"] == group]
        best = min(m["median_s"] / m["probes"] for m in rows)
        write(group)
        for m in sorted(rows, key=lambda m: m["median_s"] / m["probes"]):
            per_probe = m["median_s"] / m["probes"]
            write(f"  {m['name']:<52} {m['probes']:>6} {1e3 * per_probe:>9.2f} {per_probe / best:>7.2f} "
                  f"{m.get('bytes_per_probe', '—'):>12} {m['store_bytes']:>9} {m['peak_alloc_mb']:>14.1f}")

"""The bench suite's own summary: per benchmark, the median wall time per probe and what it cost in bytes and peak
allocation traced by tracemalloc (numpy arrays and Python objects; not Embree, OpenImageIO or HDF5 buffers).
pytest-benchmark's table has the times, not these."""

from __future__ import annotations

import pytest

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

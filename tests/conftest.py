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

"""The horizon clamp of views below the surface (``bakery.reflection.validation.clamp_view_to_horizon``, the rule the
spec and the shaders apply): every clamped view is a unit vector at n·v' = ε (HORIZON_EPSILON) — also for normals
that are unit only in float32 and for v = −n exactly, where the tangent is undefined — and views above are unchanged."""

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from bakery.reflection.validation import HORIZON_EPSILON, clamp_view_to_horizon

unit = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(lambda x: np.linalg.norm(x) > 0.1)


@settings(max_examples=200, deadline=None)
@given(normal=unit, view=unit, towards_minus_n=st.floats(0.0, 1.0))
def test_clamped_views_sit_on_the_horizon(normal, view, towards_minus_n):
    n32 = np.asarray(normal, dtype=np.float32)
    n32 = (n32 / np.linalg.norm(n32)).astype(np.float32)  # unit in float32 only, as engines upload it
    n = n32.astype(np.float64)
    v = np.asarray(view, dtype=np.float64)
    v = (1 - towards_minus_n) * v / np.linalg.norm(v) - towards_minus_n * n  # down to v = −n exactly
    assume(np.linalg.norm(v) > 1e-3)  # (v = n, weight ½: no view at all)
    v /= np.linalg.norm(v)
    out = clamp_view_to_horizon(v[None], n[None])[0]
    n_unit = n / np.linalg.norm(n)
    if v @ n_unit >= 0:
        assert np.array_equal(out, v)
    else:
        assert abs(np.linalg.norm(out) - 1) < 1e-12
        assert abs(out @ n_unit - HORIZON_EPSILON) < 1e-9

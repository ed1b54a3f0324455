"""``bakery bench sharp-chain`` end to end on the shipped environment at a small face: where a chain stores a level
at exactly the α read, it is that level (the floor, up to float16), and the chain without it is worse; as α → 0 the
chain converges to the reference of the reconstruction it is read with."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from bakery.bench.sharp_chain import FLOOR, chain_encoders, run_sharp_chain_bench
from bakery.cli import main

CITY = Path(__file__).resolve().parents[2] / "examples" / "environments" / "city_512.hdr"


def test_a_chain_read_at_one_of_its_levels_is_the_level_at_that_alpha():
    quarter, half = chain_encoders(16)["gap_levels = 2"].chain.level_alphas()[1:3]  # α_1/4, α_1/2 at 16²
    result = run_sharp_chain_bench([CITY], face_size=16, alphas=(float(quarter), float(half)), directions=200,
                                   echo=None)
    mse = {name: {float(a): v["geomean"] for a, v in by_alpha.items()}
           for name, by_alpha in result["relative_mse"].items()}
    for alpha, exact in ((quarter, "gap_levels = 2"), (half, "gap_levels = 1")):
        np.testing.assert_allclose(mse[exact][alpha], mse[FLOOR][alpha], rtol=0.05, atol=1e-6)  # float16 levels
    # α_1/4 at 16² is narrower than a texel: against the bilinear reconstruction the level gains less there
    assert mse["gap_levels = 1"][quarter] > 1.3 * mse["gap_levels = 2"][quarter]
    assert mse["no gap level"][half] > 2 * mse["gap_levels = 1"][half]
    assert mse["gap_levels = 2"][half] == mse["gap_levels = 1"][half]  # the same level, read the same way


def test_the_cli_prints_and_writes_the_table_and_refuses_alphas_above_the_chain_only_range(tmp_path):
    out = tmp_path / "out"
    run = CliRunner().invoke(main, ["bench", "sharp-chain", str(CITY), "--face-size", "8", "--directions", "50",
                                    "--max-gap-levels", "1", "-o", str(out)])
    assert run.exit_code == 0, run.output
    assert "| gap_levels = 1 |" in run.output and f"| {FLOOR} |" in run.output
    data = json.loads((out / "sharp_chain.json").read_text())
    assert set(data["relative_mse"]) == {"no gap level", "gap_levels = 1", FLOOR}
    assert (out / "sharp_chain.md").read_text().startswith("Sharp chain at face 8")
    with pytest.raises(ValueError, match="below the E0 blend"):
        run_sharp_chain_bench([CITY], face_size=8, alphas=(0.2,), directions=10, echo=None)


def test_as_alpha_goes_to_zero_a_chain_converges_to_the_bilinear_reference():
    """K_α * (bilinear capture) → the bilinear capture as α → 0, which is what a chain reads there (its α = 0 level,
    bilinear): against the supersampled reconstruction the error falls with S, against the texels (S = 1, piecewise
    constant) it stays at the difference of the two reconstructions."""
    def error(supersample):
        result = run_sharp_chain_bench([CITY], face_size=16, alphas=(0.0005,), directions=100, max_gap_levels=0,
                                       supersample=supersample, echo=None)
        assert result["protocol"]["supersample"] == supersample
        return result["relative_mse"]["no gap level"]["0.0005"]["geomean"]

    texels, fine = error(1), error(8)
    assert fine < 0.05 * texels
    with pytest.raises(ValueError, match="supersample"):
        run_sharp_chain_bench([CITY], face_size=8, alphas=(0.01,), directions=10, supersample=0, echo=None)

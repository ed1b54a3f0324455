"""Shared helpers of the farm tests: the repository's own bakery in every subprocess, a pinned bake time, the indoor
example at face size 4 and one sample per texel (fast), and a recipe whose batches make four aligned shards."""

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
INDOOR = REPO / "examples" / "indoor" / "indoor.usda"
#: Subprocesses import this checkout's bakery (farm tools run commands from other folders) and pin the bake time.
ENV = {**os.environ, "SOURCE_DATE_EPOCH": "1700000000",
       "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
BAKERY = [sys.executable, "-m", "bakery.cli"]
FAST = ["--samples", "1"]

#: 25 irradiance probes in batches of 8 (+ the sh3-only probe) and a reflection probe: 5 batches; a fitted
#: hallucination curve (finalize over every probe) and band skipping (over neighbours) run at the merge.
RECIPE = """name = "farm-test"
[targets]
irradiance = ["zh3_hallucinated", "zh3_quantized", "sh3", "zh3_deringed"]
reflection = ["shexp", "splitsum"]
[bake]
face_size = 4
reference_errors = true
[encoding_settings.zh3_hallucinated]
curve = "fit"
[pipeline]
batch_size = 8
"""


def write_recipe(folder: Path) -> Path:
    path = folder / "farm.toml"
    path.write_text(RECIPE)
    return path


def cli(*args, check: bool = True, env: dict | None = None, timeout: float = 300):  # noqa: ANN201
    result = subprocess.run([*BAKERY, *map(str, args)], capture_output=True, text=True, env=env or ENV,
                            timeout=timeout, check=False)
    if check and result.returncode != 0:
        raise AssertionError(f"bakery {' '.join(map(str, args))} exited {result.returncode}:\n{result.stderr}")
    return result


def cli_json(*args, **options) -> dict:
    return json.loads(cli(*args, "--json", **options).stdout)

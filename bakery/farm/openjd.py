"""Open Job Description job templates (``jobtemplate-2023-09``) for farm bakes: ``bakery farm openjd``.

    step BakeShards   one task per probe range of the plan's suggested chunking (task parameter ``Probes``, a
                      STRING range such as ``0-63``), each ``bakery bake SCENE --probes {{Task.Param.Probes}}
                      --plan-id ID -o {{Param.ShardDir}}/shard-{{Task.Param.Probes}}.h5``
    step Merge        depends on BakeShards: ``bakery merge <every shard> -o {{Param.Store}} --layer {{Param.Layer}}``

When the base store is up to date (the plan bakes no probe) there is no range to shard: the job is then the one
step ``Merge``, ``bakery bake SCENE -o {{Param.Store}} --layer {{Param.Layer}}``, which verifies the store and
reuses every probe (or bakes, on the one host, whatever changed after the planning). An OpenJD step needs at least
one task, so a BakeShards step without ranges would not be a valid template.

The ranges are the plan's batch-aligned chunking (:func:`bakery.pipeline.shards.suggest_chunking`), so no task
recomputes another's batch. ``--plan-id`` pins the plan the template was written for: if the scene, the settings or
the base store change before the job runs, every task fails with exit 2 and a message instead of baking a different
plan. Job parameters (scene, shard folder, store, layer, the bakery command's worker count) can be overridden at
submission (``openjd run --job-param``, Deadline Cloud's submitter). The same commands map to OpenCue and Deadline
10 (``docs/farm.md``).

The template is written as YAML (plain double-quoted scalars; JSON when the file name ends in ``.json``).
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path
from typing import Any

from bakery.files import OutputError, check_output_file, json_output_refusal, write_bytes_atomic

TEMPLATE_HEADER = "# Open Job Description job template written by `bakery farm openjd`"
PARAMETER_KEYS = frozenset({"Scene", "ShardDir", "Store", "Layer", "Jobs"})


def _default(path: Path, folder: Path) -> str | None:
    """OpenJD joins a PATH parameter's default to the template's folder and forbids walking up from it: a path
    inside the folder becomes a relative default, any other path has none (pass it at submission,
    ``job_parameters``)."""
    path, folder = Path(path).resolve(), Path(folder).resolve()
    return path.relative_to(folder).as_posix() if path.is_relative_to(folder) else None


def job_parameters(*, scene: Path, store: Path, layer: Path, shard_dir: Path, jobs: int = 1) -> dict[str, Any]:
    """The job parameter values of a bake (``openjd run --job-param file://<template>.params.json``)."""
    return {"Scene": str(Path(scene).resolve()), "ShardDir": str(Path(shard_dir).resolve()),
            "Store": str(Path(store).resolve()), "Layer": str(Path(layer).resolve()), "Jobs": jobs}


def job_template(*, name: str, scene: Path, store: Path, layer: Path, shard_dir: Path, ranges: list[str],
                 plan_id: str, bake_args: list[str], command: str = "bakery", base: bool = False,
                 jobs: int = 1, template_dir: Path = Path(".")) -> dict[str, Any]:
    """The job template as data. ``bake_args``: the bake settings options, passed to every shard as given; path
    defaults are relative to ``template_dir`` (where the template is written), when they lie inside it."""
    program, *prefix = shlex.split(command)
    defaults = {key: _default(path, template_dir) for key, path in
                (("Scene", scene), ("ShardDir", shard_dir), ("Store", store), ("Layer", layer))}
    shard = "{{Param.ShardDir}}/shard-{{Task.Param.Probes}}.h5"
    bake = [*prefix, "bake", "{{Param.Scene}}", "--probes", "{{Task.Param.Probes}}", "--plan-id", plan_id,
            "-o", shard, "--jobs", "{{Param.Jobs}}", "--json", *bake_args]
    if base:
        bake += ["--base", "{{Param.Store}}"]
    merge = [*prefix, "merge", *(f"{{{{Param.ShardDir}}}}/shard-{r}.h5" for r in ranges), "-o", "{{Param.Store}}",
             "--layer", "{{Param.Layer}}", "--json"]
    steps = [{"name": "BakeShards",
              "parameterSpace": {"taskParameterDefinitions": [
                  {"name": "Probes", "type": "STRING", "range": list(ranges)}]},
              "script": {"actions": {"onRun": {"command": program, "args": bake}}}},
             {"name": "Merge",
              "dependencies": [{"dependsOn": "BakeShards"}],
              "script": {"actions": {"onRun": {"command": program, "args": merge}}}}]
    description = f"bakery bake of {Path(scene).name} in {len(ranges)} probe-range tasks and a merge (plan {plan_id})"
    if not ranges:  # the store is up to date: one bake that verifies and reuses it (module docstring)
        rebake = [*prefix, "bake", "{{Param.Scene}}", "-o", "{{Param.Store}}", "--layer", "{{Param.Layer}}",
                  "--jobs", "{{Param.Jobs}}", "--json", *bake_args]
        steps = [{"name": "Merge", "script": {"actions": {"onRun": {"command": program, "args": rebake}}}}]
        description = (f"bakery bake of {Path(scene).name}: the store was up to date when planned (plan {plan_id}); "
                       "one task verifies it and bakes whatever changed since")
    return {
        "specificationVersion": "jobtemplate-2023-09",
        "name": name,
        "description": description,
        "parameterDefinitions": [
            _path_parameter("Scene", "FILE", "IN", defaults["Scene"], "The USD scene (or image) to bake."),
            _path_parameter("ShardDir", "DIRECTORY", "OUT", defaults["ShardDir"], "Shared folder of the shard stores."),
            _path_parameter("Store", "FILE", "OUT", defaults["Store"], "The merged probe store."),
            _path_parameter("Layer", "FILE", "OUT", defaults["Layer"], "The baked-results USD layer."),
            {"name": "Jobs", "type": "INT", "default": jobs, "minValue": 1,
             "description": "Worker processes of each bake task (bakery --jobs)."},
        ],
        "steps": steps,
    }


def _path_parameter(name: str, kind: str, flow: str, default: str | None, description: str) -> dict[str, Any]:
    parameter = {"name": name, "type": "PATH", "objectType": kind, "dataFlow": flow}
    if default is not None:
        parameter["default"] = default
    parameter["description"] = description
    return parameter


def _scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    return json.dumps(str(value), ensure_ascii=False)  # a JSON string is a YAML double-quoted scalar


def to_yaml(value: Any, indent: int = 0) -> str:
    """Block-style YAML of plain dicts, lists, strings and integers."""
    pad = " " * indent
    lines: list[str] = []
    if isinstance(value, dict):
        for key, item in value.items():
            if isinstance(item, (dict, list)) and item:
                lines.append(f"{pad}{key}:")
                lines.append(to_yaml(item, indent + 2))
            else:
                lines.append(f"{pad}{key}: {_scalar(item) if not isinstance(item, (dict, list)) else '[]'}")
    elif isinstance(value, list):
        for item in value:
            if isinstance(item, dict) and item:
                body = to_yaml(item, indent + 2).splitlines()
                lines.append(f"{pad}- {body[0].lstrip()}")
                lines.extend(body[1:])
            elif isinstance(item, list):
                lines.append(f"{pad}-")
                lines.append(to_yaml(item, indent + 2))
            else:
                lines.append(f"{pad}- {_scalar(item)}")
    else:
        lines.append(pad + _scalar(value))
    return "\n".join(lines)


def write_template(path: Path, template: dict[str, Any]) -> Path:
    if path.suffix.lower() == ".json":
        text = json.dumps(template, indent=2) + "\n"
    else:
        text = TEMPLATE_HEADER + "\n" + to_yaml(template) + "\n"
    return write_bytes_atomic(path, text.encode())


def parameters_path(template: Path) -> Path:
    """Where the job parameter values of ``template`` are written (``<template stem>.params.json``)."""
    return Path(template).with_name(Path(template).stem + ".params.json")


def _read_head(path: Path, size: int = 1 << 16) -> bytes:
    with open(path, "rb") as handle:
        return handle.read(size)


def template_refusal(path: Path) -> str | None:
    """Why an existing file must not be replaced by a job template (None: a template ``bakery farm openjd`` wrote:
    YAML with its header line, or JSON naming a ``bakery`` job)."""
    try:
        head = _read_head(path)
        if head.startswith(TEMPLATE_HEADER.encode()):
            return None
        data = json.loads(Path(path).read_bytes()) if head.lstrip().startswith(b"{") else None
    except (OSError, ValueError):
        data = None
    if isinstance(data, dict) and str(data.get("specificationVersion", "")).startswith("jobtemplate-") \
            and str(data.get("name", "")).startswith("bakery "):
        return None
    return "exists and is not a job template written by bakery farm openjd"


def parameters_refusal(path: Path) -> str | None:
    """Why an existing file must not be replaced by the job parameter values (None: values bakery wrote)."""
    return json_output_refusal(path, PARAMETER_KEYS, "a job parameter file written by bakery farm openjd")


def check_template_outputs(template: Path, inputs: list[Path], force: bool = False) -> None:
    """The output policy (:func:`bakery.files.check_output_file`) for the template and its parameter file: new
    paths, or files ``bakery farm openjd`` wrote; never one of ``inputs`` (the scene, its layers, the store, …),
    not even with ``force``."""
    template = Path(template)
    if template.suffix.lower() not in (".yaml", ".yml", ".json"):
        raise OutputError(f"{template}: a job template is a .yaml, .yml or .json file")
    check_output_file(template, "job template", inputs=inputs, refusal=template_refusal, force=force)
    check_output_file(parameters_path(template), "job parameters", inputs=[*inputs, template],
                      refusal=parameters_refusal, force=force)

"""The ``bakery`` command line (click). Thin: parses arguments, calls the library, prints, maps errors to exit codes.

Exit codes: 0 success; 1 unexpected failure; 2 bad input (missing/corrupt file, bad scene); 3 bad settings;
4 an encoding failed; 5 ``check`` found errors.
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from bakery.errors import BakeryError, BakeryWarning

SCENE_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
console = Console(stderr=True, soft_wrap=True)
out = Console(soft_wrap=True)


def _show_warning(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
    console.print(f"[yellow]warning:[/yellow] {message}")


class _Group(click.Group):
    def invoke(self, ctx: click.Context):
        warnings.showwarning = _show_warning
        warnings.simplefilter("always", BakeryWarning)
        try:
            return super().invoke(ctx)
        except BakeryError as error:
            console.print(f"[red]error:[/red] {error}")
            sys.exit(error.exit_code)


@click.group(cls=_Group)
@click.version_option(package_name="bakery")
def main() -> None:
    """bakery: bake irradiance and reflection light probes from environments and USD scenes."""


@main.command()
@click.argument("source", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), help="Store (.h5). Default: SOURCE with .h5.")
@click.option("--encodings", "-e", multiple=True, help="Encodings to bake (repeatable). Default: all for the probes.")
@click.option("--face-size", type=int, default=None, help="Bake-grid cube face size (default 64 for images).")
@click.option("--layout", type=click.Choice(["equirect", "cube", "angular"]), help="Force the image layout.")
@click.option("--layer", type=click.Path(path_type=Path), help="USD layer to write (scenes; default STORE.usda).")
@click.option("--no-reference", is_flag=True, help="Skip error-vs-reference diagnostics.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
def bake(source: Path, output: Path | None, encodings: tuple[str, ...], face_size: int | None, layout: str | None,
         layer: Path | None, no_reference: bool, as_json: bool) -> None:
    """Bake SOURCE: an environment image (one distant probe) or a USD scene (its probes)."""
    from bakery.bake import BakeSettings

    output = output or source.with_suffix(".h5")
    if source.suffix.lower() in SCENE_SUFFIXES:
        from bakery.scene_bake import bake_scene

        summary = bake_scene(source, output, layer, face_size=face_size or 32, encodings=list(encodings) or None)
        if as_json:
            out.print_json(json.dumps(summary, default=str))
        else:
            console.print(f"baked {summary.get('probes', '?')} probes → {output}")
        return
    from bakery.bake import bake_environment

    settings = BakeSettings(face_size=face_size or 64, encodings=encodings, reference_errors=not no_reference)
    result = bake_environment(source, output, settings, layout=layout)
    summary = {
        "store": str(result.store_path), "probes": len(result.probes), "settings_hash": result.settings_hash,
        "encodings": {n: e.bytes_per_probe() for n, e in result.encodings.items()},
        "timings_s": result.timings, "warnings": result.warnings,
        "reference_error": {k.split("/", 1)[1]: float(v[0]) for k, v in result.diagnostics.items()
                            if k.startswith("reference_error/")},
    }
    if as_json:
        out.print_json(json.dumps(summary))
    else:
        console.print(f"baked {source} → {result.store_path} ({len(result.encodings)} encodings)")


@main.command()
@click.argument("store", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def inspect(store: Path, as_json: bool) -> None:
    """Print a store's format version, conventions, probes, encodings and bytes per probe."""
    from bakery.api import open_store

    s = open_store(store)
    info = {
        "format": s.attributes.get("format"), "format_version": s.format_version,
        "bakery_version": s.attributes.get("bakery_version"), "settings_hash": s.attributes.get("settings_hash"),
        "conventions": s.conventions, "probes": len(s.probe_names),
        "encodings": {n: {"kind": e.kind, "version": e.version, "bytes_per_probe": e.bytes_per_probe,
                          "probes": e.probe_count, "settings": e.settings} for n, e in s.encodings.items()},
    }
    if as_json:
        out.print_json(json.dumps(info, default=str))
        return
    out.print(f"[bold]{store}[/bold]: {info['format']} {info['format_version']} (bakery {info['bakery_version']})")
    out.print(f"settings hash {info['settings_hash']}")
    conventions = Table("convention", "value", title="conventions", show_lines=False)
    for key, value in s.conventions.items():
        conventions.add_row(key, value)
    out.print(conventions)
    out.print(f"{len(s.probe_names)} probes: " + ", ".join(s.probe_names[:10]) + (" …" if len(s.probe_names) > 10 else ""))
    table = Table("encoding", "kind", "version", "probes", "bytes/probe", "description", title="encodings")
    for name, e in s.encodings.items():
        table.add_row(name, e.kind, e.version, str(e.probe_count), str(e.bytes_per_probe), e.description)
    out.print(table)


@main.group()
def bench() -> None:
    """Quality and speed benchmarks against independent references."""


@bench.command("irradiance")
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results"), show_default=True)
@click.option("--face-size", type=int, default=64, show_default=True)
def bench_irradiance(folder: Path, output: Path, face_size: int) -> None:
    """Relative RMSE of every irradiance encoding against the exact irradiance, for every image in FOLDER."""
    from bakery.bench.irradiance import format_table, run_irradiance_bench, write_results

    result = run_irradiance_bench(folder, face_size=face_size)
    json_path, text_path = write_results(result, output)
    out.print(format_table(result))
    console.print(f"wrote {json_path} and {text_path}")


@bench.command("reflection")
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results"), show_default=True)
@click.option("--speed", is_flag=True, help="Also measure probes/s of the fits and prefilters.")
@click.option("--face-size", type=int, default=128, show_default=True)
def bench_reflection(folder: Path, output: Path, speed: bool, face_size: int) -> None:
    """SH-exponential vs split-sum reflection error against the reference (seed 000 Fig. 4–7 protocol)."""
    from bakery.bench.reflection import run_reflection_bench

    run_reflection_bench(folder, output, speed=speed, face_size=face_size)
    console.print(f"wrote results to {output}")


@main.command()
@click.argument("scene", type=click.Path(path_type=Path))
def check(scene: Path) -> None:
    """Check a USD scene for problems, per prim; exit 5 if any error."""
    from bakery.usd.check import check_scene

    issues = check_scene(scene)
    errors = 0
    for issue in issues:
        colour = "red" if issue.severity == "error" else "yellow"
        errors += issue.severity == "error"
        out.print(f"[{colour}]{issue.severity}[/{colour}] {issue.prim}: {issue.message}")
    out.print(f"{len(issues)} issue(s), {errors} error(s)")
    if errors:
        sys.exit(5)


if __name__ == "__main__":  # pragma: no cover
    main()

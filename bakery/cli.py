"""The ``bakery`` command line (click). Thin: parses arguments, calls the library, prints, maps errors to exit codes.

Exit codes: 0 success; 1 unexpected failure; 2 bad input (missing/corrupt file, bad scene); 3 bad settings;
4 an encoding failed; 5 ``check`` found errors; 6 the store was written but some probes failed.
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
    from bakery.allocator import tune_allocator

    tune_allocator()  # large batch temporaries stay in the heap (bakery/allocator.py)


class _Progress:
    """A rich progress bar (probes/s, ETA) on a terminal; silent elsewhere."""

    def __init__(self, enabled: bool) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self.progress = Progress(TextColumn("baking"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("{task.fields[rate]}"), TimeRemainingColumn(), console=console,
                                 disable=not enabled)
        self.task = None
        self.start = None

    def __enter__(self):
        import time

        self.progress.__enter__()
        self.start = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.progress.__exit__(*exc)

    def __call__(self, done: int, total: int) -> None:
        import time

        if self.task is None:
            self.task = self.progress.add_task("bake", total=total, rate="")
        rate = done / max(time.perf_counter() - self.start, 1e-9)
        self.progress.update(self.task, completed=done, total=total, rate=f"{rate:.1f} probes/s")


@main.command()
@click.argument("sources", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), help="Store (.h5). Default: SOURCE with .h5.")
@click.option("--recipe", "-r", help="Recipe preset (mobile, console, pc-high, reference) or TOML path.")
@click.option("--encodings", "-e", multiple=True, help="Encodings to bake (repeatable); overrides the recipe.")
@click.option("--face-size", type=int, default=None,
              help="Bake-grid cube face size (default 64 images, 32 scenes).")
@click.option("--layout", type=click.Choice(["equirect", "cube", "angular"]), help="Force the image layout.")
@click.option("--layer", type=click.Path(path_type=Path),
              help="USD layer of baked attributes, .usda or .usdc (scenes; default <store stem>.bake.usda).")
@click.option("--samples", type=click.IntRange(min=1), default=None, help="Rays per cube texel (scenes; default 4).")
@click.option("--bounces", type=click.IntRange(min=0), default=None, help="Diffuse bounces (scenes; default 1).")
@click.option("--seed", type=int, default=None, help="Base seed of the per-probe capture seeds (scenes).")
@click.option("--jobs", "-j", type=click.IntRange(min=1), default=None,
              help="Worker processes (default: number of cores).")
@click.option("--scheduler", help="Dask scheduler address (tcp://host:port) to bake on a farm.")
@click.option("--dask-local", is_flag=True, help="Use a local Dask cluster of --jobs workers.")
@click.option("--dry-run", is_flag=True, help="Print the plan (probes, reuse, batches) and exit.")
@click.option("--no-resume", is_flag=True, help="Ignore checkpoints of an interrupted bake and the existing store.")
@click.option("--no-reference", is_flag=True, help="Skip error-vs-reference diagnostics.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
def bake(sources: tuple[Path, ...], output: Path | None, recipe: str | None, encodings: tuple[str, ...],
         face_size: int | None, layout: str | None, layer: Path | None, samples: int | None, bounces: int | None,
         seed: int | None, jobs: int | None, scheduler: str | None, dask_local: bool, dry_run: bool,
         no_resume: bool, no_reference: bool, as_json: bool) -> None:
    """Bake SOURCES: environment images (one distant probe each) or one USD scene (its probes).

    Exit codes: 0 all probes baked; 6 the store was written but some probes failed (listed); 2/3 bad input or
    settings (nothing written).
    """
    from bakery.pipeline.executors import make_executor
    from bakery.pipeline.run import bake as run_bake
    from bakery.pipeline.run import check_output_paths, load_previous, plan_bake
    from bakery.pipeline.settings import request_from
    from bakery.sources import source_for

    request = request_from(
        sources, output, recipe=recipe, encodings=encodings, face_size=face_size, layer=layer, layout=layout,
        samples=samples, bounces=bounces, seed=seed, resume=not no_resume,
        reference_errors=False if no_reference else None,
    )
    if dry_run:
        source = source_for(request.sources, request.layout, request.capture)
        check_output_paths(request, source)
        _, plan = plan_bake(request, source, load_previous(request.output) if request.resume else None)
        info = {"store": str(request.output), "probes": len(plan.tasks), "reused": len(plan.reused),
                "to_bake": plan.to_bake, "batches": len(plan.batches), "skipped": plan.skipped,
                "settings_hash": request.settings.hash(),
                "encodings": sorted({e for t in plan.tasks for e in t.encodings})}
        if as_json:
            out.print_json(json.dumps(info))
        else:
            out.print(f"plan for {request.output}: {info['probes']} probes, {info['reused']} unchanged (reused), "
                      f"{info['to_bake']} to bake in {info['batches']} batches; encodings: "
                      + ", ".join(info["encodings"]))
            for skip in plan.skipped:
                out.print(f"  skipped {skip['probe']}: {skip['reason']}")
        return
    executor = make_executor(jobs, scheduler, dask_local)
    try:
        with _Progress(console.is_terminal and not as_json) as progress:
            summary = run_bake(request, executor, progress)
    finally:
        executor.close()
    if as_json:
        out.print_json(json.dumps(summary.as_dict(), default=str))
    else:
        console.print(f"{request.output}: {summary.baked} probes baked, {summary.reused} unchanged, "
                      f"{len(summary.failed)} failed in {summary.seconds:.1f} s "
                      f"({summary.probes_per_second:.1f} probes/s, {summary.workers} {summary.executor} workers)"
                      + (f"; layer {summary.layer}" if summary.layer else ""))
        for name, message in summary.failed.items():
            console.print(f"[red]failed[/red] {name}: {message}")
    if summary.failed:
        sys.exit(6)


@main.command()
@click.argument("a", type=click.Path(path_type=Path))
@click.argument("b", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True)
def diff(a: Path, b: Path, as_json: bool) -> None:
    """Which probes differ between stores A and B, and by how much (per encoding, relative L2 of stored values)."""
    from bakery.store.diff import diff_stores

    report = diff_stores(a, b)
    if as_json:
        out.print_json(json.dumps(report, default=str))
        return
    out.print(f"added {len(report['added'])}, removed {len(report['removed'])}, changed {len(report['changed'])}, "
              f"unchanged {report['unchanged']}")
    for name in report["added"]:
        out.print(f"+ {name}")
    for name in report["removed"]:
        out.print(f"- {name}")
    for name, change in report["changed"].items():
        worst = max(change.values()) if change else 0.0
        out.print(f"~ {name}: max relative change {worst:.3g} " + ", ".join(f"{k}={v:.3g}" for k, v in change.items()))


@main.command()
@click.argument("store", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), help="Write the upgraded store here (default: in place).")
@click.option("--dry-run", is_flag=True, help="Say what would change.")
def migrate(store: Path, output: Path | None, dry_run: bool) -> None:
    """Upgrade STORE to the current store format version."""
    from bakery.store.format import FORMAT_VERSION, migrate_store

    steps = migrate_store(store, output, dry_run=dry_run)
    if not steps:
        out.print(f"{store} is already format {FORMAT_VERSION}")
    for step in steps:
        out.print(("would migrate: " if dry_run else "migrated: ") + step)


@main.command()
@click.argument("store", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@click.option("--probes", "pattern", help="List the probes whose prim path matches this glob (e.g. '/World/*').")
@click.option("--region", help="List the probes inside the box xmin,ymin,zmin,xmax,ymax,zmax (metres, bake frame).")
def inspect(store: Path, as_json: bool, pattern: str | None, region: str | None) -> None:
    """Print a store's format version, conventions, probes, encodings and bytes per probe; with --probes/--region,
    list the selected probes with their position and the bake that produced them."""
    from bakery.api import open_store

    s = open_store(store)
    if pattern or region:
        box = None
        if region:
            try:
                box = tuple(float(v) for v in region.split(","))
                assert len(box) == 6
            except (ValueError, AssertionError):
                raise click.BadParameter("--region takes six comma-separated numbers") from None
        rows = []
        for i in s.select_probes(pattern, box):
            bake = s.history[s.probe_bake_ids[i]] if s.history else {}
            rows.append({"name": s.probe_names[i], "kinds": s.probe_kinds[i],
                         "position": [float(v) for v in s.probe_positions[i]], "content_hash": s.probe_hashes[i],
                         "baked": bake.get("time_utc", ""), "bakery_version": bake.get("bakery_version", "")})
        if as_json:
            out.print_json(json.dumps(rows))
            return
        table = Table("probe", "kinds", "position (m)", "baked", "content hash", title=f"{len(rows)} probes")
        for row in rows:
            table.add_row(row["name"], row["kinds"], ", ".join(f"{v:.3g}" for v in row["position"]), row["baked"],
                          row["content_hash"][:12])
        out.print(table)
        return
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
    table = Table("encoding", "kind", "version", "probes", "bytes/probe", "total bytes", title="encodings")
    for name, e in s.encodings.items():
        table.add_row(name, e.kind, e.version, str(e.probe_count), str(e.bytes_per_probe),
                      f"{e.bytes_per_probe * e.probe_count:,}")
    out.print(table)
    if s.history:
        last = s.history[-1]
        out.print(f"last bake {last.get('time_utc')} (bakery {last.get('bakery_version')}); "
                  f"{len(s.history)} bake(s) in the history")
    skipped = json.loads(s.attributes.get("skipped", "[]"))
    for skip in skipped:
        out.print(f"skipped {skip.get('encoding') or skip.get('probe')}: {skip['reason']}")
    for note in json.loads(s.attributes.get("roughness_ranges", "[]")):
        out.print(f"roughness range {note['probe']}: {note['reason']}")


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
@click.option("--no-plain", is_flag=True, help="Do not score the plain 1024-sample split-sum chain (~20 s/probe).")
def bench_reflection(folder: Path, output: Path, speed: bool, face_size: int, no_plain: bool) -> None:
    """SH-exponential vs split-sum reflection error against the reference (seed 000 Fig. 4–7 protocol)."""
    from bakery.bench.reflection import run_reflection_bench

    run_reflection_bench(folder, output, speed=speed, face_size=face_size, plain_splitsum=not no_plain)
    console.print(f"wrote results to {output}")


@main.command()
@click.argument("store", type=click.Path(path_type=Path))
@click.option("-o", "--output", "out_dir", type=click.Path(path_type=Path), required=True,
              help="Folder for report.html and report.json.")
@click.option("--environment", type=click.Path(path_type=Path), default=None,
              help="Capture image for references (default: the store's source).")
@click.option("--no-previews", is_flag=True, help="Skip the sphere preview renders.")
def report(store: Path, out_dir: Path, environment: Path | None, no_previews: bool) -> None:
    """Write DIR/report.html + report.json: memory and quality of STORE, per encoding and probe."""
    from bakery.report import write_report

    paths = write_report(store, out_dir, environment=environment, previews=not no_previews)
    console.print(f"wrote {paths['html']} and {paths['json']}")


@bench.command("pareto")
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results"), show_default=True)
@click.option("--quick", is_flag=True, help="Fewer parameters and environments.")
def bench_pareto(folder: Path, output: Path, quick: bool) -> None:
    """Run time against error for every encoding and its parameters; Pareto table, plot and JSON."""
    from bakery.bench.pareto import format_pareto_table, run_pareto_bench

    out.print(format_pareto_table(run_pareto_bench(folder, output, quick=quick)))


@bench.command("scale")
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results/scale"), show_default=True)
@click.option("--volume", default="25,16,25", show_default=True, help="Irradiance volume counts nx,ny,nz.")
@click.option("--reflection", type=int, default=1000, show_default=True, help="Number of reflection probes.")
@click.option("--recipe", default="console", show_default=True)
@click.option("--face-size", type=int, default=16, show_default=True)
def bench_scale(output: Path, volume: str, reflection: int, recipe: str, face_size: int) -> None:
    """Wall time, peak memory and store size of a generated large scene with 1 and 2 workers."""
    from bakery.bench.scale import run_scale_bench

    counts = tuple(int(v) for v in volume.split(","))
    result = run_scale_bench(output, counts, reflection, recipe, face_size)
    out.print_json(json.dumps(result))


@main.command()
@click.argument("scene", type=click.Path(path_type=Path))
def check(scene: Path) -> None:
    """Check a USD scene for problems, per prim; exit 5 if any error."""
    from bakery.usd.check import check_exit_code, check_scene

    issues = check_scene(scene)
    errors = 0
    for issue in issues:
        colour = "red" if issue.severity == "error" else "yellow"
        errors += issue.severity == "error"
        out.print(f"[{colour}]{issue.severity}[/{colour}] {issue.prim}: {issue.message}")
    out.print(f"{len(issues)} issue(s), {errors} error(s)")
    if check_exit_code(issues):
        sys.exit(check_exit_code(issues))


if __name__ == "__main__":  # pragma: no cover
    main()

"""The ``bakery`` command line (click). Thin: parses arguments, calls the library, prints, maps errors to exit codes.

Exit codes: 0 success; 1 unexpected failure; 2 bad input (missing/corrupt file, bad scene) or usage; 3 bad settings;
4 an encoding failed; 5 ``check`` found errors; 6 the store was written but some probes failed; 130 stopped by
Ctrl-C (SIGINT) and 143 by SIGTERM, each with one line (``interrupted: …`` / ``terminated: …``) saying what was
kept, and no traceback — from the first import of this module on.
"""

from __future__ import annotations

import sys

try:  # Ctrl-C while the command line loads (≈ 0.3 s): the same one line and exit code as later, not a traceback
    import json
    import warnings
    from pathlib import Path
    from typing import Any, NoReturn

    import click
    import numpy as np
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from bakery.conventions import SEED_RANGE
    from bakery.environment.layouts import LAYOUTS
    from bakery.errors import BakeryError, BakeryWarning, ConfigError, SceneError
except KeyboardInterrupt:
    sys.stderr.write("interrupted: bakery was stopped while it started; nothing was written\n")
    raise SystemExit(130) from None

console = Console(stderr=True, soft_wrap=True)
out = Console(soft_wrap=True)

#: Exit statuses of a command stopped by a signal (128 + the signal's number, as a shell reports it).
INTERRUPTED_EXIT_CODE, TERMINATED_EXIT_CODE = 130, 143


class _Stopped(SystemExit):
    """The exit of a command stopped by Ctrl-C or SIGTERM, its one-line message printed."""


def _stopped(code: int, message: str) -> NoReturn:
    """Print ``interrupted: message`` (Ctrl-C, exit 130) or ``terminated: message`` (SIGTERM, 143) and exit."""
    word = "interrupted" if code == INTERRUPTED_EXIT_CODE else "terminated"
    console.print(f"[red]{word}:[/red] {escape(message)}")
    raise _Stopped(code)


def _is_sigterm(exit: SystemExit) -> bool:
    """Whether ``exit`` is SIGTERM turned into a clean unwind: ``SystemExit(143)`` from
    :func:`bakery.files.terminate_as_exit` (bakes, merges, exports, ``farm calibrate``)."""
    return not isinstance(exit, _Stopped) and exit.code == TERMINATED_EXIT_CODE


def _journal_note(output: Path) -> str:
    """"; the finished batches are kept in S.h5.partial and the next bake resumes from them", if there are some."""
    from bakery.files import OutputError
    from bakery.pipeline.journal import Journal

    try:
        journal = Journal(output).directory
    except OutputError:  # a work folder the bake refused: nothing of ours is in it
        return ""
    if journal.is_dir() and any(journal.glob("*.pkl")):
        return f"; the finished batches are kept in {journal} and the next bake resumes from them"
    return ""


def _print_json(data: Any) -> None:
    """Every ``--json`` output: strict JSON (numpy values as numbers, NaN/inf as null: ``jq`` and browsers refuse
    ``NaN``/``Infinity``), other objects as text."""
    from bakery.files import jsonable

    out.print_json(json.dumps(jsonable(data), default=str, allow_nan=False))


def _count(n: int, noun: str) -> str:
    """'1 probe', '2 probes', '1 batch', '3 batches'."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}{'es' if noun.endswith(('s', 'ch')) else 's'}"


def _show_warning(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
    console.print(f"[yellow]warning:[/yellow] {escape(str(message))}")


class _Group(click.Group):
    group_class = type  # ``bench`` and ``farm`` are _Groups too (their commands' names in the messages below)

    def make_context(self, *args, **kwargs) -> click.Context:  # noqa: ANN002, ANN003
        try:
            return super().make_context(*args, **kwargs)
        except KeyboardInterrupt:  # click would print "Aborted!" and exit 1
            _stopped(INTERRUPTED_EXIT_CODE, "bakery was stopped while it started; nothing was written")

    def invoke(self, ctx: click.Context):
        warnings.showwarning = _show_warning
        warnings.simplefilter("always", BakeryWarning)
        try:
            return super().invoke(ctx)
        except _Stopped:  # a command said what it kept
            raise
        except KeyboardInterrupt:  # anywhere else (imports, planning, …): click would print "Aborted!" and exit 1
            _stopped(INTERRUPTED_EXIT_CODE, f"{self._command_name(ctx)} was stopped before it finished")
        except SystemExit as exit:
            if _is_sigterm(exit):
                _stopped(TERMINATED_EXIT_CODE, f"{self._command_name(ctx)} was stopped before it finished")
            raise
        except BakeryError as error:
            console.print(f"[red]error:[/red] {escape(str(error))}")
            sys.exit(error.exit_code)
        except OSError as error:  # a file-system failure the library did not name (permissions, full disk, …)
            from bakery.files import os_error_message

            console.print(f"[red]error:[/red] {escape(os_error_message(error))}")
            sys.exit(2)

    @staticmethod
    def _command_name(ctx: click.Context) -> str:
        """``bakery farm calibrate`` (whatever the program was called: ``python -m bakery.cli``, …)."""
        names = [ctx.invoked_subcommand] if ctx.invoked_subcommand else []
        while ctx.parent is not None:
            names.insert(0, ctx.info_name)
            ctx = ctx.parent
        return " ".join(["bakery", *names])


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
        self.progress.update(self.task, completed=done, total=total, rate=f"{rate:.3g} probes/s")


def _bake_left(request) -> str:  # noqa: ANN001 - a BakeRequest, or None before it was made
    """What a bake stopped before it wrote its outputs leaves (it removed what it staged on the way out)."""
    if request is None:
        return "bakery bake was stopped before it started; nothing was written"
    return f"{request.output}: the previous store and layer are unchanged" + _journal_note(request.output)


def _check_executor_options(scheduler: str | None, dask_local: bool) -> None:
    if scheduler and dask_local:
        raise click.UsageError("--scheduler and --dask-local exclude each other: bake on the Dask scheduler at "
                               f"{scheduler}, or on a local Dask cluster")


def _scheduler_address(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:  # noqa: ARG001
    """``--scheduler``: ``tcp://HOST:PORT`` (or ``tls://``, ``ucx://``, ``inproc://…``); a bare ``HOST:PORT`` is tcp."""
    if value is None:
        return None
    import re

    address = value if "://" in value else f"tcp://{value}"
    scheme, _, rest = address.partition("://")
    if scheme == "inproc":
        return address
    match = re.fullmatch(r"(\[[0-9a-fA-F:]+\]|[A-Za-z0-9_.-]+):(\d{1,5})", rest)
    if scheme not in ("tcp", "tls", "ucx", "ws", "wss") or not match or not 0 < int(match.group(2)) < 65536:
        raise click.BadParameter(f"{value!r} is not a scheduler address; expected tcp://HOST:PORT")
    return address


@main.command()
@click.argument("sources", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), help="Store (.h5). Default: SOURCE with .h5.")
@click.option("--recipe", "-r", help="Recipe preset (mobile, console, pc-high, reference) or TOML path.")
@click.option("--encodings", "-e", multiple=True, help="Encodings to bake (repeatable); overrides the recipe.")
@click.option("--face-size", type=int, default=None,
              help="Bake-grid cube face size (default 64 images, 32 scenes).")
@click.option("--layout", type=click.Choice(LAYOUTS), help="Force the image layout.")
@click.option("--layer", type=click.Path(path_type=Path),
              help="USD layer of baked attributes, .usda or .usdc (scenes; default <store stem>.bake.usda).")
@click.option("--samples", type=click.IntRange(min=1), default=None, help="Rays per cube texel (scenes; default 4).")
@click.option("--bounces", type=click.IntRange(min=0), default=None,
              help="Largest number of bounces, Russian roulette from the 4th (scenes; default 64).")
@click.option("--seed", type=click.IntRange(*SEED_RANGE), default=None,
              help="Base seed of the per-probe capture seeds (scenes).")
@click.option("--target-noise", type=click.FloatRange(min=0.0, max=1.0, max_open=True), default=None,
              help="Adaptive capture: add rays until each probe's relative SH noise is below this (scenes; 0 = off).")
@click.option("--time", "time_code", type=float, default=None,
              help="USD time code to read the scene at (default: authored defaults, else the earliest sample).")
@click.option("--jobs", "-j", type=click.IntRange(min=1), default=None,
              help="Worker processes (default: number of cores).")
@click.option("--scheduler", callback=_scheduler_address,
              help="Dask scheduler address (tcp://host:port) to bake on a farm.")
@click.option("--dask-local", is_flag=True, help="Use a local Dask cluster of --jobs workers.")
@click.option("--dry-run", is_flag=True, help="Print the plan (probes, reuse, batches) and exit.")
@click.option("--no-resume", is_flag=True, help="Ignore checkpoints of an interrupted bake and the existing store.")
@click.option("--no-reference", is_flag=True, help="Skip error-vs-reference diagnostics.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.option("--force", is_flag=True,
              help="Replace an existing file at the store or layer path even if it is not a previous bakery output "
                   "(never an input of the bake).")
def bake(sources: tuple[Path, ...], output: Path | None, recipe: str | None, encodings: tuple[str, ...],
         face_size: int | None, layout: str | None, layer: Path | None, samples: int | None, bounces: int | None,
         seed: int | None, jobs: int | None, scheduler: str | None, dask_local: bool, dry_run: bool,
         no_resume: bool, no_reference: bool, as_json: bool, force: bool, target_noise: float | None = None,
         time_code: float | None = None) -> None:
    """Bake SOURCES: environment images (one distant probe each) or one USD scene (its probes).

    The store (and layer) may only replace a previous bakery store (layer); anything else at those paths is
    refused unless --force. Exit codes: 0 all probes baked; 6 the store was written but some probes failed
    (listed); 2/3 bad input, output or settings (nothing written).
    """
    _check_executor_options(scheduler, dask_local)
    request = executor = None
    try:  # Ctrl-C or SIGTERM until the outputs are written: one line saying what is left (the bake cleaned up)
        from dataclasses import replace

        from bakery.pipeline.executors import make_executor
        from bakery.pipeline.run import bake as run_bake
        from bakery.pipeline.run import check_output_paths, load_previous, plan_bake
        from bakery.pipeline.settings import request_from
        from bakery.sources import source_for

        request = request_from(
            sources, output, recipe=recipe, encodings=encodings, face_size=face_size, layer=layer, layout=layout,
            samples=samples, bounces=bounces, seed=seed, resume=not no_resume,
            reference_errors=False if no_reference else None, target_noise=target_noise, time=time_code,
        )
        request = replace(request, force=force)
        source = source_for(request.sources, request.layout, request.capture)
        check_output_paths(request, source)  # before any work (also before a Dask cluster starts)
        if dry_run:
            _, plan = plan_bake(request, source, load_previous(request.output) if request.resume else None)
            info = {"store": str(request.output), "probes": len(plan.tasks), "reused": len(plan.reused),
                    "to_bake": plan.to_bake, "batches": len(plan.batches), "skipped": plan.skipped,
                    "settings_hash": request.settings.hash(),
                    "encodings": sorted({e for t in plan.tasks for e in t.encodings})}
            if as_json:
                _print_json(info)
            else:
                out.print(f"plan for {request.output}: {_count(info['probes'], 'probe')}, {info['reused']} "
                          f"unchanged (reused), {info['to_bake']} to bake in {_count(info['batches'], 'batch')}; "
                          "encodings: " + ", ".join(info["encodings"]))
                for skip in plan.skipped:
                    out.print(f"  skipped {escape(str(skip['probe']))}: {escape(str(skip['reason']))}")
            return
        executor = make_executor(jobs, scheduler, dask_local)
        with _Progress(console.is_terminal and not as_json) as progress:
            summary = run_bake(request, executor, progress)
    except KeyboardInterrupt:
        _stopped(INTERRUPTED_EXIT_CODE, _bake_left(request))
    except SystemExit as exit:  # SIGTERM during the bake (turned into SystemExit(143)): the same unwind
        if _is_sigterm(exit):
            _stopped(TERMINATED_EXIT_CODE, _bake_left(request))
        raise
    finally:
        if executor is not None:
            executor.close()
    # ---- recipe `exports` (bakery export after the bake; issue 13) -------------------------------------------
    if recipe:
        _run_recipe_exports(recipe, request.output, summary.layer)
    # -----------------------------------------------------------------------------------------------------------
    if as_json:
        _print_json(summary.as_dict())
    else:
        console.print(f"{request.output}: {summary.baked} probe{'s' if summary.baked != 1 else ''} baked, "
                      f"{summary.reused} unchanged, "
                      f"{len(summary.failed)} failed in {summary.seconds:.1f} s "
                      f"({summary.probes_per_second:.3g} probes/s; {summary.workers} "
                      f"worker{'s' if summary.workers != 1 else ''}, {summary.executor})"
                      + (f"; {summary.resumed_batches} batches resumed from checkpoints" if summary.resumed_batches
                         else "")
                      + (f"; layer {summary.layer}" if summary.layer else ""))
        for name, message in summary.failed.items():
            console.print(f"[red]failed[/red] {escape(name)}: {escape(message)}")
    if summary.failed:
        sys.exit(6)


@main.command()
@click.argument("a", type=click.Path(path_type=Path))
@click.argument("b", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True)
def diff(a: Path, b: Path, as_json: bool) -> None:
    """Which probes differ between stores A and B, and by how much (per encoding, relative L2 of stored values).

    Says "identical" when both stores hold the same probes, encodings and stored values. Exit codes: 0 the stores
    were compared (identical or not); 2 a store cannot be read."""
    from bakery.store.diff import diff_stores

    report = diff_stores(a, b)
    if as_json:
        _print_json(report)
        return
    if report["identical"]:
        out.print(f"identical: {_count(report['unchanged'], 'probe')}, {_count(len(report['encodings']), 'encoding')}, "
                  "same stored values")
        return
    out.print(f"added {len(report['added'])}, removed {len(report['removed'])}, changed {len(report['changed'])}, "
              f"unchanged {report['unchanged']}"
              + (f", moved {len(report['moved'])}" if report["moved"] else "")
              + (f", not compared {len(report['not_compared'])} (no encoding in common)" if report["not_compared"]
                 else ""))
    for key, sign in (("encodings_added", "+"), ("encodings_removed", "-")):
        if report[key]:
            out.print(f"{sign} encoding{'s' if len(report[key]) > 1 else ''} {', '.join(report[key])} (only in "
                      f"{b if sign == '+' else a}: not compared)")
    for name in report["added"]:
        out.print(f"+ {escape(name)}")
    for name in report["removed"]:
        out.print(f"- {escape(name)}")
    for name, change in report["changed"].items():
        worst = max(change.values()) if change else 0.0
        out.print(f"~ {escape(name)}: max relative change {worst:.3g} " + ", ".join(f"{k}={v:.3g}" for k, v in change.items()))
    for name, distance in report["moved"].items():
        out.print(f"> {escape(name)}: moved " + (f"{distance:.3g} m" if distance is not None else "(non-finite position)"))
    for name in report["not_compared"]:
        out.print(f"? {escape(name)}: in both stores, with no encoding in common (not compared)")


@main.command()
@click.argument("store", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), help="Write the upgraded store here (default: in place).")
@click.option("--dry-run", is_flag=True, help="Say what would change.")
@click.option("--force", is_flag=True, help="Let -o replace a file that is not a bakery store (never STORE itself).")
def migrate(store: Path, output: Path | None, dry_run: bool, force: bool) -> None:
    """Upgrade STORE to the current store format version."""
    from bakery.files import FileLock
    from bakery.pipeline.run import check_store_output
    from bakery.store.format import FORMAT_VERSION, migrate_store

    target = output if output is not None and output.resolve() != store.resolve() else None
    if target is not None:
        check_store_output(target, [store], force)
    if dry_run:
        steps = migrate_store(store, target, dry_run=True)
    else:
        with FileLock(target or store):  # the file being written (a bake of it waits for no one: it is refused)
            steps = migrate_store(store, target)
    if not steps:
        out.print(f"{store} is already format {FORMAT_VERSION}"
                  + (f"; {'would write' if dry_run else 'wrote'} it unchanged to {target}" if target else ""))
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
    from bakery.store.format import failed_probes

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
            if "capture/sh_noise" in s.diagnostics:  # achieved relative SH noise of the capture (issue 11)
                rows[-1]["sh_noise"] = float(np.asarray(s.diagnostics["capture/sh_noise"])[i])
            if "capture/backface_fraction" in s.diagnostics:  # share of camera rays that saw back faces
                rows[-1]["backface_fraction"] = float(np.asarray(s.diagnostics["capture/backface_fraction"])[i])
        if as_json:
            # sh_noise is inf/NaN where it was not measured: null (strict JSON)
            _print_json(rows)
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
        "conventions": s.conventions, "probes": len(s.probe_names), "checksums_verified": s.verified,
        "encodings": {n: {"kind": e.kind, "version": e.version, "bytes_per_probe": e.bytes_per_probe,
                          "probes": e.probe_count, "settings": e.settings} for n, e in s.encodings.items()},
        "failed_probes": failed_probes(s.attributes),
    }
    if as_json:
        _print_json(info)
        return
    out.print(f"[bold]{store}[/bold]: {info['format']} {info['format_version']} (bakery {info['bakery_version']})")
    out.print(f"settings hash {info['settings_hash']}")
    out.print("checksums verified" if s.verified else
              f"no checksums (format {info['format_version']}; `bakery migrate` adds them)")
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
                  f"{_count(len(s.history), 'bake')} in the history")
    failed = info["failed_probes"]
    if failed:
        out.print(f"[red]failed:[/red] {_count(len(failed), 'probe')} failed in the bake and "
                  f"{'is' if len(failed) == 1 else 'are'} not in this store:")
        for name, reason in failed.items():
            out.print(f"  {escape(name)}: {escape(reason.removeprefix(name + ': '))}")
    skipped = s.json_attribute("skipped")
    for skip in skipped:
        out.print(f"skipped {escape(str(skip.get('encoding') or skip.get('probe')))}: {escape(str(skip['reason']))}")
    for note in s.json_attribute("roughness_ranges"):
        out.print(f"roughness range {escape(str(note['probe']))}: {escape(str(note['reason']))}")
    if "capture/sh_noise" in s.diagnostics:  # capture settings and achieved noise (issue 11)
        noise = np.asarray(s.diagnostics["capture/sh_noise"], dtype=np.float64)
        noise = noise[np.isfinite(noise)]
        a = s.attributes
        if noise.size:
            out.print(f"capture: {a.get('capture_samples')} rays/texel, ≤ {a.get('capture_bounces')} bounces, target "
                      f"noise {a.get('capture_target_noise', 0)}; SH noise median {np.median(noise):.3g}, "
                      f"max {noise.max():.3g} ({_count(noise.size, 'rendered probe')})")
        sampling = s.json_attribute("capture_light_sampling")
        if sampling and sampling.get("drawn"):
            out.print(f"lights: {sampling['lights']}; {sampling['draws_per_vertex']} of the {sampling['non_distant']} "
                      f"non-distant ones drawn per path vertex from the light grid (all sampled up to "
                      f"{sampling['enumerated_up_to']})")
    if "capture/backface_fraction" in s.diagnostics:  # probe validity
        from bakery.conventions import INSIDE_BACKFACE_FRACTION
        from bakery.pipeline.merge import inside_geometry

        threshold = float(s.attributes.get("inside_geometry_backface_fraction", INSIDE_BACKFACE_FRACTION))
        inside = inside_geometry(s.diagnostics, threshold)
        names = ", ".join(s.probe_names[i] for i in inside[:5]) + (" …" if inside.size > 5 else "")
        out.print(f"validity: {_count(inside.size, 'probe')} likely inside geometry (≥ {threshold:.0%} of their rays see "
                  f"back faces){': ' + names if inside.size else ''}")
        if "capture/offset" in s.diagnostics:
            offset = np.linalg.norm(np.asarray(s.diagnostics["capture/offset"], dtype=np.float64), axis=-1)
            moved = np.flatnonzero(offset > 0)
            if moved.size:
                out.print(f"relocated: {_count(moved.size, 'probe')} captured from outside the geometry they were in "
                          f"(bakery:volume:relocate; largest offset {offset[moved].max():.3g} m)")
        from bakery.pipeline.dilate import NEIGHBOURS_KEY

        sources = np.nan_to_num(np.asarray(s.diagnostics.get(NEIGHBOURS_KEY, ()), dtype=np.float64))
        if np.any(sources > 0):
            out.print(f"dilated: {_count(int(np.count_nonzero(sources > 0)), 'probe')} inside geometry store the inverse-square-"
                      "distance-weighted mean of their volume's valid probes (bakery:volume:dilate)")


@main.group()
def bench() -> None:
    """Quality and speed benchmarks against independent references."""


@bench.command("irradiance")
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results"), show_default=True)
@click.option("--face-size", type=int, default=64, show_default=True)
@click.option("--force", is_flag=True, help="Replace result files in the folder that bench did not write.")
def bench_irradiance(folder: Path, output: Path, face_size: int, force: bool) -> None:
    """Relative RMSE of every irradiance encoding against the exact irradiance, for every image in FOLDER."""
    from bakery.bench.irradiance import format_table, run_irradiance_bench, write_results
    from bakery.bench.output import check_bench_outputs

    check_bench_outputs(output, ("irradiance.json", "irradiance.md"), force)
    result = run_irradiance_bench(folder, face_size=face_size)
    json_path, text_path = write_results(result, output, force=force)
    out.print(format_table(result))
    console.print(f"wrote {json_path} and {text_path}")


@bench.command("reflection")
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results"), show_default=True)
@click.option("--speed", is_flag=True, help="Also measure probes/s of the fits and prefilters.")
@click.option("--face-size", type=int, default=128, show_default=True)
@click.option("--no-plain", is_flag=True, help="Do not score the plain 1024-sample split-sum chain (~20 s/probe).")
@click.option("--gap-level", is_flag=True, help="Score shexp_hybrid with its gap_level setting (one more level "
              "at alpha_1/2 at the capture's face).")
@click.option("--gap-levels", type=click.IntRange(1, 4), default=1, show_default=True,
              help="With --gap-level: how many gap levels (2: also alpha_1/4).")
@click.option("--force", is_flag=True, help="Replace result files in the folder that bench did not write.")
def bench_reflection(folder: Path, output: Path, speed: bool, face_size: int, no_plain: bool, gap_level: bool,
                     gap_levels: int, force: bool) -> None:
    """SH-exponential vs split-sum reflection error against the reference (seed 000 Fig. 4–7 protocol)."""
    from bakery.bench.reflection import run_reflection_bench

    run_reflection_bench(folder, output, speed=speed, face_size=face_size, plain_splitsum=not no_plain, force=force,
                         hybrid_gap_levels=gap_levels if gap_level else 0)
    console.print(f"wrote results to {output}")


@main.command()
@click.argument("store", type=click.Path(path_type=Path))
@click.option("-o", "--output", "out_dir", type=click.Path(path_type=Path), required=True,
              help="Folder for report.html and report.json.")
@click.option("--environment", type=click.Path(path_type=Path), default=None,
              help="Capture image for references (default: the store's source).")
@click.option("--no-previews", is_flag=True, help="Skip the sphere preview renders.")
@click.option("--force", is_flag=True, help="Replace report.html/report.json in DIR even if bakery did not write them.")
def report(store: Path, out_dir: Path, environment: Path | None, no_previews: bool, force: bool) -> None:
    """Write DIR/report.html + report.json: memory and quality of STORE, per encoding and probe."""
    from bakery.report import write_report

    paths = write_report(store, out_dir, environment=environment, previews=not no_previews, force=force)
    console.print(f"wrote {paths['html']} and {paths['json']}")


@bench.command("pareto")
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results"), show_default=True)
@click.option("--quick", is_flag=True, help="Fewer parameters and environments.")
@click.option("--force", is_flag=True, help="Replace result files in the folder that bench did not write.")
def bench_pareto(folder: Path, output: Path, quick: bool, force: bool) -> None:
    """Run time against error for every encoding and its parameters; Pareto table, plot and JSON."""
    from bakery.bench.pareto import format_pareto_table, run_pareto_bench

    out.print(format_pareto_table(run_pareto_bench(folder, output, quick=quick, force=force)))


@bench.command("shexp-fit")
@click.argument("folder", required=False, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results/shexp"), show_default=True)
@click.option("--batch-size", type=click.IntRange(min=1), default=64, show_default=True)
@click.option("--face-size", type=click.IntRange(min=8), default=128, show_default=True)
@click.option("--repeats", type=click.IntRange(min=5), default=7, show_default=True)
@click.option("--processes", type=click.IntRange(min=1), default=2, show_default=True,
              help="Single-threaded processes of the bake-configuration throughput (1: skip it).")
@click.option("--force", is_flag=True, help="Replace result files in the folder that bench did not write.")
def bench_shexp(folder: Path | None, output: Path, batch_size: int, face_size: int, repeats: int,
                processes: int, force: bool) -> None:
    """SH-exponential fit speed per probe: the fused fit against the step-by-step one, side by side, and the
    throughput of bake-like single-threaded workers (FOLDER: HDR environments; default synthetic sky-and-sun
    captures)."""
    from bakery.bench.output import check_bench_outputs, write_bench_file
    from bakery.bench.shexp_fit import run_shexp_fit_bench

    check_bench_outputs(output, ("shexp.json",), force)
    result = run_shexp_fit_bench(folder, batch_size=batch_size, face_size=face_size, repeats=repeats, echo=click.echo,
                                 processes=processes)
    write_bench_file(output, "shexp.json", json.dumps(result, indent=2, default=str), force)


@bench.command("split-sum")
@click.argument("environments", nargs=-1, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results/splitsum"), show_default=True)
@click.option("--face-size", type=click.IntRange(min=8), default=128, show_default=True)
@click.option("--repeats", type=click.IntRange(min=1), default=5, show_default=True)
@click.option("--no-fis", is_flag=True, help="Skip the (slow) filtered-importance-sampling formulation.")
@click.option("--force", is_flag=True, help="Replace result files in the folder that bench did not write.")
def bench_splitsum(environments: tuple[Path, ...], output: Path, face_size: int, repeats: int, no_fis: bool,
                   force: bool) -> None:
    """Split-sum and hybrid chain prefilter per probe: cached sparse operators against filtered importance sampling,
    side by side, with each level's error against the exact prefilter (ENVIRONMENTS: HDR images; default the
    shipped examples')."""
    from bakery.bench.output import check_bench_outputs, write_bench_file
    from bakery.bench.splitsum import run_splitsum_bench

    check_bench_outputs(output, ("splitsum.json",), force)
    result = run_splitsum_bench(face_size=face_size, env_paths=list(environments) or None, repeats=repeats,
                                fis_batch_sizes=() if no_fis else (1,), echo=click.echo)
    write_bench_file(output, "splitsum.json", json.dumps(result, indent=2, default=str), force)


@bench.command("sharp-chain")
@click.argument("environments", nargs=-1, required=True,
                type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results/sharp-chain"),
              show_default=True)
@click.option("--face-size", type=click.IntRange(min=8), default=64, show_default=True)
@click.option("--directions", type=click.IntRange(min=1), default=600, show_default=True)
@click.option("--max-gap-levels", type=click.IntRange(0, 4), default=2, show_default=True,
              help="Score shexp_hybrid without gap levels and with 1 … this many.")
@click.option("--supersample", type=click.IntRange(min=1), default=4, show_default=True,
              help="The reference filters the capture's bilinear reconstruction at this many times the face size "
                   "(1: its texels, piecewise constant).")
@click.option("--force", is_flag=True, help="Replace result files in the folder that bench did not write.")
def bench_sharp_chain(environments: tuple[Path, ...], output: Path, face_size: int, directions: int,
                      max_gap_levels: int, supersample: int, force: bool) -> None:
    """The hybrid's chain below its first kernel level (alpha 0.003-0.03), with 0, 1, 2 … gap levels, against the
    kernel applied exactly, and the floor of a level at exactly each alpha (ENVIRONMENTS: HDR images)."""
    from bakery.bench.output import check_bench_outputs, write_bench_file
    from bakery.bench.sharp_chain import format_table, run_sharp_chain_bench

    check_bench_outputs(output, ("sharp_chain.json", "sharp_chain.md"), force)
    result = run_sharp_chain_bench(list(environments), face_size=face_size, directions=directions,
                                   max_gap_levels=max_gap_levels, supersample=supersample, echo=click.echo)
    write_bench_file(output, "sharp_chain.json", json.dumps(result, indent=2), force)
    write_bench_file(output, "sharp_chain.md", format_table(result) + "\n", force)


class IntList(click.ParamType):
    """Comma-separated integers ≥ ``minimum`` (``count`` of them when given), e.g. ``25,16,25``."""

    name = "INTS"

    def __init__(self, minimum: int, count: int | None = None) -> None:
        self.minimum, self.count = minimum, count

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201
        if isinstance(value, tuple):
            return value
        try:
            numbers = tuple(int(v) for v in str(value).split(","))
        except ValueError:
            numbers = ()
        if not numbers or any(n < self.minimum for n in numbers) or (self.count and len(numbers) != self.count):
            size = f"{self.count} " if self.count else ""
            self.fail(f"{value!r} is not {size}comma-separated integers >= {self.minimum}", param, ctx)
        return numbers


@bench.command("scale")
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results/scale"), show_default=True)
@click.option("--volume", type=IntList(1, 3), default="25,16,25", show_default=True,
              help="Irradiance volume counts nx,ny,nz.")
@click.option("--reflection", type=click.IntRange(min=0), default=1000, show_default=True,
              help="Number of reflection probes.")
@click.option("--recipe", default="console", show_default=True)
@click.option("--face-size", type=click.IntRange(min=1), default=16, show_default=True)
@click.option("--jobs", "jobs", type=IntList(1), default="1,2", show_default=True,
              help="Worker counts to run, comma-separated.")
@click.option("--repeats", type=click.IntRange(min=1), default=1, show_default=True,
              help="Bake each worker count this many times, alternating; report the median of each.")
@click.option("--production", is_flag=True,
              help="Issue 14's production scene: 10,000 irradiance probes at 32², 1,000 reflection probes at 128² "
                   "(console recipe), 2 workers, KTX2 export; overrides the other options.")
@click.option("--force", is_flag=True, help="Replace result files in the folder that bench did not write.")
def bench_scale(output: Path, volume: tuple[int, ...], reflection: int, recipe: str, face_size: int,
                jobs: tuple[int, ...], repeats: int, production: bool, force: bool) -> None:
    """Wall time, per-stage timings, peak memory and store size of a generated large scene."""
    from bakery.bench.scale import PRODUCTION, run_scale_bench

    def progress_bar() -> _Progress:
        return _Progress(console.is_terminal)

    if production:
        result = run_scale_bench(output, **PRODUCTION, progress_bar=progress_bar, repeats=repeats, force=force)
    else:
        result = run_scale_bench(output, volume, reflection, recipe, face_size, jobs=jobs, progress_bar=progress_bar,
                                 repeats=repeats, force=force)
    _print_json(result)


@bench.command("capture")
@click.argument("scenes", nargs=-1, type=click.Path(exists=True, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("bench-results/capture"), show_default=True)
@click.option("--face-size", type=int, default=32, show_default=True)
@click.option("--samples", type=click.IntRange(min=1), default=4, show_default=True)
@click.option("--bounces", type=click.IntRange(min=0), default=None, help="Default: the capture's default (64).")
@click.option("--target-noise", type=float, default=0.0, show_default=True)
@click.option("--probes", type=int, default=None, help="Render only the first N probes of each scene.")
@click.option("--processes", type=click.IntRange(min=1), default=1, show_default=True,
              help="Render in this many worker processes (aggregate rays/s).")
@click.option("--force", is_flag=True, help="Replace result files in the folder that bench did not write.")
def bench_capture(scenes: tuple[Path, ...], output: Path, face_size: int, samples: int, bounces: int | None,
                  target_noise: float, probes: int | None, processes: int, force: bool) -> None:
    """Capture speed (rays/s, probes/s) and achieved SH noise of the examples (or SCENES)."""
    from bakery.bench.capture import run_capture_bench

    result = run_capture_bench(scenes, output, face_size=face_size, samples=samples, bounces=bounces,
                               target_noise=target_noise, probes=probes, processes=processes, force=force)
    _print_json(result)


@main.command()
@click.argument("scene", type=click.Path(path_type=Path))
def check(scene: Path) -> None:
    """Check a USD scene for problems, per prim; exit 5 if any error (also a file USD cannot parse); exit 2 if SCENE
    is missing, a folder or not a USD file."""
    from bakery.sources.usd_scene import SCENE_SUFFIXES

    if scene.is_dir():
        raise SceneError(f"{scene}: is a directory, not a USD scene file")
    if not scene.is_file():
        raise SceneError(f"{scene}: scene not found")
    if scene.suffix.lower() not in SCENE_SUFFIXES:
        raise SceneError(f"{scene}: not a USD scene (expected {', '.join(SCENE_SUFFIXES)})")
    from bakery.usd.check import check_exit_code, check_scene

    issues = check_scene(scene)
    errors = 0
    for issue in issues:
        colour = "red" if issue.severity == "error" else "yellow"
        errors += issue.severity == "error"
        where = issue.layer or str(scene)  # the sublayer or asset that defines the prim, else the scene
        out.print(f"{escape(where)}: [{colour}]{issue.severity}[/{colour}]: {escape(str(issue.prim))}: "
                  f"{escape(issue.message)}")  # file: severity: prim: message, as compilers print them
    out.print(f"{_count(len(issues), 'issue')}, {_count(errors, 'error')}")
    if check_exit_code(issues):
        sys.exit(check_exit_code(issues))


# --- farm bakes (issue 16): shards of a plan, their merge, the plan, job templates ---------------------------------
def _add_shard_options(command: click.Command) -> None:
    """``bakery bake --probes A-B | --shard i/n [--base STORE] [--plan-id ID]``: bake one shard of the plan
    (:mod:`bakery.pipeline.shards`) instead of the whole bake; every other option of ``bake`` means the same."""
    import functools

    callback = command.callback

    def wrapper(*args, probes=None, shard=None, base=None, plan_id=None, **params):  # noqa: ANN002, ANN003, ANN202
        if probes is None and shard is None:
            if base is not None or plan_id is not None:
                raise click.UsageError("--base and --plan-id apply to a shard (--probes A-B or --shard i/n)")
            return callback(*args, **params)
        return _bake_shard(params, probes, shard, base, plan_id)

    command.callback = functools.update_wrapper(wrapper, callback)
    command.params.extend([
        click.Option(["--probes"], help="Bake only these probes of the plan's work order (A-B, inclusive; see "
                                        "`bakery plan`) into the shard store -o, for `bakery merge`."),
        click.Option(["--shard"], help="Bake the i-th of n shards (i/n, 1-based) of the plan's suggested chunking."),
        click.Option(["--base"], type=click.Path(path_type=Path),
                     help="Shards: plan against this store (the farm's final store); its unchanged probes are reused "
                          "by the merge."),
        click.Option(["--plan-id"], help="Shards: refuse to bake (exit 2) unless the plan's id is this one."),
    ])


_add_shard_options(bake)


def _request(params: dict, output: Path | None):  # noqa: ANN202
    from dataclasses import replace

    from bakery.pipeline.settings import request_from

    request = request_from(
        params["sources"], output, recipe=params.get("recipe"), encodings=params.get("encodings") or (),
        face_size=params.get("face_size"), layer=params.get("layer"), layout=params.get("layout"),
        samples=params.get("samples"), bounces=params.get("bounces"), seed=params.get("seed"),
        resume=not params.get("no_resume", False), reference_errors=False if params.get("no_reference") else None,
        target_noise=params.get("target_noise"), time=params.get("time_code"),  # shards: the bake's own options
    )
    if params.get("force") and "force" in request.__dataclass_fields__:
        request = replace(request, force=True)
    return request


def _bake_shard(params: dict, probes: str | None, shard: str | None, base: Path | None, plan_id: str | None) -> None:
    from bakery.pipeline.executors import make_executor
    from bakery.pipeline.shards import ShardSpec, bake_shard, parse_probe_range, parse_shard, plan_shard

    _check_executor_options(params.get("scheduler"), params.get("dask_local", False))
    if params.get("output") is None:
        raise click.UsageError("a shard needs -o SHARD.h5 (its own store, merged later by `bakery merge`)")
    if params.get("layer") is not None:
        raise click.UsageError("a shard writes no layer; give --layer to `bakery merge`")
    request = _request(params, params["output"])
    spec = ShardSpec(probes=parse_probe_range(probes) if probes is not None else None,
                     shard=parse_shard(shard) if shard is not None else None, base=base, plan_id=plan_id)
    if params.get("dry_run"):
        from bakery.pipeline.shards import format_range, work_order

        _, plan, identity, probe_range, _ = plan_shard(request, spec)
        info = {"store": str(request.output), "plan_id": identity, "range": format_range(probe_range),
                "work_probes": plan.to_bake,
                "probes": work_order(plan)[probe_range[0]: probe_range[1] + 1] if probe_range else []}
        _print_json(info) if params.get("as_json") else out.print(
            f"shard of plan {identity}: probes {info['range']} of {plan.to_bake} ({len(info['probes'])} probes)")
        return
    executor = make_executor(params.get("jobs"), params.get("scheduler"), params.get("dask_local", False))
    try:
        with _Progress(console.is_terminal and not params.get("as_json")) as progress:
            summary = bake_shard(request, spec, executor, progress)
    except KeyboardInterrupt:
        _stopped(INTERRUPTED_EXIT_CODE, f"{request.output}: the previous shard store is unchanged"
                 + _journal_note(request.output))
    except SystemExit as exit:
        if _is_sigterm(exit):
            _stopped(TERMINATED_EXIT_CODE, f"{request.output}: the previous shard store is unchanged"
                     + _journal_note(request.output))
        raise
    finally:
        executor.close()
    console.print(summary.log_line())  # the task log: range, rays/s, time
    if params.get("as_json"):
        _print_json(summary.as_dict())
    for name, message in summary.failed.items():
        console.print(f"[red]failed[/red] {escape(name)}: {escape(message)}")
    if summary.failed:
        sys.exit(6)


def _settings_options(command):  # noqa: ANN001, ANN202
    """The bake settings of ``bakery bake`` (same names and meaning) for ``plan`` and ``farm openjd``."""
    options = [
        click.option("--recipe", "-r", help="Recipe preset (mobile, console, pc-high, reference) or TOML path."),
        click.option("--encodings", "-e", multiple=True, help="Encodings to bake (repeatable); overrides the recipe."),
        click.option("--face-size", type=int, default=None, help="Bake-grid cube face size."),
        click.option("--layout", type=click.Choice(LAYOUTS), help="Force the image layout."),
        click.option("--samples", type=click.IntRange(min=1), default=None, help="Rays per cube texel (scenes)."),
        click.option("--bounces", type=click.IntRange(min=0), default=None,
                     help="Largest number of bounces, Russian roulette from the 4th (scenes; default 64)."),
        click.option("--seed", type=click.IntRange(*SEED_RANGE), default=None,
                     help="Base seed of the per-probe capture seeds (scenes)."),
        click.option("--no-reference", is_flag=True, help="Skip error-vs-reference diagnostics."),
    ]
    for option in reversed(options):
        command = option(command)
    return command


def _settings_args(params: dict) -> list[str]:
    """The settings options of ``params`` as ``bakery bake`` arguments (recipe files made absolute)."""
    args: list[str] = []
    if params.get("recipe"):
        recipe = params["recipe"]
        args += ["--recipe", str(Path(recipe).resolve()) if Path(recipe).is_file() else recipe]
    for name in params.get("encodings") or ():
        args += ["-e", name]
    for key, flag in (("face_size", "--face-size"), ("layout", "--layout"), ("samples", "--samples"),
                      ("bounces", "--bounces"), ("seed", "--seed")):
        if params.get(key) is not None:
            args += [flag, str(params[key])]
    if params.get("no_reference"):
        args.append("--no-reference")
    return args


@main.command("plan")
@click.argument("sources", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path),
              help="The store the bake would write (its unchanged probes are reused). Default: SOURCE with .h5.")
@_settings_options
@click.option("--no-resume", is_flag=True, help="Plan a clean bake (ignore the existing store).")
@click.option("--tasks", "-n", type=click.IntRange(min=1), default=4, show_default=True,
              help="Suggest a chunking of the work into this many farm tasks.")
@click.option("--calibration", type=click.Path(path_type=Path),
              help="Cost calibration JSON (`bakery farm calibrate`; default: $BAKERY_CALIBRATION, else bakery's).")
@click.option("--json", "as_json", is_flag=True, help="Print the plan as JSON on stdout.")
def plan_command(sources: tuple[Path, ...], output: Path | None, tasks: int, calibration: Path | None,
                 as_json: bool, **params) -> None:  # noqa: ANN003
    """The bake plan of SOURCES without baking: probes by kind, reused and to bake, batches, the estimated cost
    per probe and per task, and a chunking for N farm tasks (`bakery bake --probes A-B` ranges)."""
    from bakery.farm.plan import plan_info

    request = _request({**params, "sources": sources}, output)
    info = plan_info(request, tasks, None if params.get("no_resume") else request.output, calibration)
    if as_json:
        _print_json(info)
        return
    probes, estimate, chunking = info["probes"], info["estimate"], info["chunking"]
    kinds = ", ".join(f"{v} {k}" for k, v in sorted(probes["by_kind"].items()))
    out.print(f"plan {info['plan_id']} for {info['store']}: {_count(probes['total'], 'probe')} ({kinds}), "
              f"{info['reused']} reused, {info['to_bake']} to bake in {_count(len(info['batches']), 'batch')}; "
              "encodings: "
              + ", ".join(info["encodings"]))
    out.print("estimated: " + ", ".join(f"{v * 1000:.2f} ms per {k} probe" for k, v in
                                        estimate["seconds_per_probe"].items())
              + f"; {estimate['one_process_seconds']:.1f} s in one process")
    pilot = estimate["capture"].get("pilot")
    if pilot:
        out.print("capture from a pilot of the scene: " + ", ".join(
            f"{rho:.2f} rays per camera ray ({kind})" for kind, rho in pilot["rays_per_camera_ray"].items())
            + f", {pilot['seconds_per_ray'] * 1e9:.0f} ns per ray on this machine")
    out.print(f"{chunking['useful_tasks']} tasks: " + ", ".join(
        f"{r} (~{s:.1f} s)" for r, s in zip(chunking["ranges"], chunking["estimated_seconds"]))
        + f"; merge ~{chunking['merge_seconds']:.1f} s")
    if chunking["note"]:
        out.print(f"note: {escape(chunking['note'])}")
    for skip in info["skipped"]:
        out.print(f"  skipped {escape(str(skip['probe']))}: {escape(str(skip['reason']))}")


@main.command()
@click.argument("shards", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, help="The merged store (.h5).")
@click.option("--layer", type=click.Path(path_type=Path),
              help="USD layer of baked attributes (scenes; default <store stem>.bake.usda).")
@click.option("--scene", "sources", multiple=True, type=click.Path(path_type=Path),
              help="The scene (or images) where the merge host sees them, if not where the shards recorded them.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
def merge(shards: tuple[Path, ...], output: Path, layer: Path | None, sources: tuple[Path, ...],
          as_json: bool) -> None:
    """Merge the shard stores of one plan (files, or folders of them) into STORE and its layer: the same bytes as a
    one-process `bakery bake`. Exit 2 if the shards do not cover the plan exactly once (the missing and duplicated
    ranges are named) or belong to different plans; 6 if some probes failed (the store is written)."""
    from bakery.pipeline.shards import merge_shards

    try:
        summary = merge_shards(list(shards), output, layer, tuple(sources) or None)
    except KeyboardInterrupt:
        _stopped(INTERRUPTED_EXIT_CODE, f"{output}: the previous store and layer are unchanged")
    except SystemExit as exit:
        if _is_sigterm(exit):
            _stopped(TERMINATED_EXIT_CODE, f"{output}: the previous store and layer are unchanged")
        raise
    if as_json:
        _print_json(summary.as_dict())
    else:
        console.print(f"{output}: merged {summary.shards} shards of plan {summary.plan_id}: {summary.baked} probes "
                      f"baked, {summary.reused} reused, {len(summary.failed)} failed in {summary.seconds:.1f} s"
                      + (f"; layer {summary.layer}" if summary.layer else ""))
    for name, message in summary.failed.items():
        console.print(f"[red]failed[/red] {escape(name)}: {escape(message)}")
    if summary.failed:
        sys.exit(6)


@main.group()
def farm() -> None:
    """Farm bakes: job templates for farm schedulers, and the cost calibration `bakery plan` uses."""


@farm.command("openjd")
@click.argument("sources", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", "template", type=click.Path(path_type=Path), required=True,
              help="The job template to write (.yaml, or .json).")
@click.option("--store", type=click.Path(path_type=Path), help="The merged store (default: SOURCE with .h5).")
@click.option("--layer", type=click.Path(path_type=Path), help="The baked layer (default: <store stem>.bake.usda).")
@click.option("--shard-dir", type=click.Path(path_type=Path),
              help="Shared folder of the shard stores (default: <store stem>.shards beside the store).")
@_settings_options
@click.option("--tasks", "-n", type=click.IntRange(min=1), default=4, show_default=True,
              help="Bake tasks (at most one per batch of the plan).")
@click.option("--jobs", "-j", type=click.IntRange(min=1), default=1, show_default=True,
              help="Worker processes of each task (the job parameter Jobs).")
@click.option("--command", "bakery_command", default="bakery", show_default=True,
              help="How farm hosts run bakery (e.g. 'python -m bakery.cli').")
@click.option("--no-resume", is_flag=True, help="A clean bake: do not reuse the existing store's probes.")
@click.option("--calibration", type=click.Path(path_type=Path), help="Cost calibration JSON for the chunking.")
@click.option("--force", "force_template", is_flag=True,
              help="Let -o (and its .params.json) replace files bakery did not write (never an input).")
def farm_openjd(sources: tuple[Path, ...], template: Path, store: Path | None, layer: Path | None,
                shard_dir: Path | None, tasks: int, jobs: int, bakery_command: str, calibration: Path | None,
                force_template: bool, **params) -> None:  # noqa: ANN003
    """Write an Open Job Description job template for SOURCES: one task per probe range of the plan (bakery bake
    --probes) and a dependent merge step (bakery merge). Validate with `openjd check`, run with `openjd run`.
    The template and <template stem>.params.json are written only to new paths or over files this command wrote
    (--force: any file but an input of the bake); exit 2 otherwise, before any work."""
    from bakery.farm.openjd import (
        check_template_outputs,
        job_parameters,
        job_template,
        parameters_path,
        write_template,
    )
    from bakery.farm.plan import plan_info
    from bakery.files import write_bytes_atomic
    from bakery.sources import default_layer_path

    if len(sources) > 1 and any(s.suffix.lower() in (".usd", ".usda", ".usdc", ".usdz") for s in sources):
        raise click.UsageError("bake one USD scene at a time")
    sources = tuple(s.resolve() for s in sources)
    protected = [*sources, *([calibration] if calibration else []), *([store] if store else []),
                 *([layer] if layer else [])]
    check_template_outputs(template, protected, force_template)
    if store is not None:
        store.resolve().parent.mkdir(parents=True, exist_ok=True)  # the job's output folder
    request = _request({**params, "sources": sources}, store.resolve() if store else None)
    store = request.output.resolve()
    base = None if params.get("no_resume") else store
    info = plan_info(request, tasks, base, calibration)
    layer = (layer or default_layer_path(store)).resolve()
    shard_dir = (shard_dir or store.with_name(f"{store.stem}.shards")).resolve()
    if len(sources) != 1:
        raise click.UsageError("farm templates bake one scene or one image (the Scene job parameter)")
    check_template_outputs(template, [*protected, *map(Path, info["inputs"]), store, layer], force_template)
    _check_farm_outputs(layer, shard_dir, [*sources, *map(Path, info["inputs"]), store])
    body = job_template(name=f"bakery {sources[0].name}", scene=sources[0], store=store, layer=layer,
                        shard_dir=shard_dir, ranges=info["chunking"]["ranges"], plan_id=info["plan_id"],
                        bake_args=_settings_args(params), command=bakery_command,
                        base=base is not None and store.is_file(), jobs=jobs, template_dir=template.resolve().parent)
    write_template(template, body)
    values = job_parameters(scene=sources[0], store=store, layer=layer, shard_dir=shard_dir, jobs=jobs)
    parameters = parameters_path(template)
    write_bytes_atomic(parameters, (json.dumps(values, indent=2) + "\n").encode())
    ranges = info["chunking"]["ranges"]
    work = (f"{len(ranges)} bake tasks ({', '.join(ranges)}) and a merge into {store}" if ranges else
            f"{store} is up to date: one task that verifies it and bakes whatever changes before the job runs")
    console.print(f"wrote {template}: {work} (plan {info['plan_id']}); "
                  f"estimated makespan {info['chunking']['makespan_seconds']:.0f} s; job parameters in {parameters} "
                  f"(openjd run {template} --job-param file://{parameters})")


def _check_farm_outputs(layer: Path, shard_dir: Path, inputs: list[Path]) -> None:
    """What the job's merge and shard tasks will write, checked now rather than on the farm after every bake task
    ran: the layer by a bake's policy (a new path or a bakery layer; never an input such as one of the scene's
    layers) and the shard folder (a folder, or a path where one can be made)."""
    from bakery.files import OutputError, check_output_file
    from bakery.pipeline.run import layer_overwrite_refusal

    if shard_dir.exists() and not shard_dir.is_dir():
        raise OutputError(f"{shard_dir}: --shard-dir exists and is not a folder; the shard tasks write their stores "
                          "into it")
    if layer.parent.is_dir():  # a missing folder is made by the merge task, on the farm's file system
        check_output_file(layer, "layer", inputs=inputs, refusal=layer_overwrite_refusal)


@farm.command("calibrate")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="Where to write the calibration JSON (use it with --calibration or $BAKERY_CALIBRATION).")
@click.option("--force", is_flag=True, help="Let -o replace a file that is not a calibration bakery wrote.")
def farm_calibrate(output: Path, force: bool) -> None:
    """Measure the cost model's constants on this machine (eight bakes of the scale bench's generated hall, three
    merges and a pilot; about a minute)."""
    from bakery.farm.calibrate import calibrate

    try:
        data = calibrate(output, force=force)
    except KeyboardInterrupt:  # calibrate removed its temporary bakes on the way out
        _stopped(INTERRUPTED_EXIT_CODE, f"{output}: not written (a previous file is unchanged); the calibration's "
                                        "temporary bakes were removed")
    except SystemExit as exit:
        if _is_sigterm(exit):
            _stopped(TERMINATED_EXIT_CODE, f"{output}: not written (a previous file is unchanged); the calibration's "
                                           "temporary bakes were removed")
        raise
    console.print(f"wrote {output} ({len(data['encodings'])} encodings; process {data['process_seconds']:.2f} s, "
                  f"{data['seconds_per_ray'] * 1e9:.1f} ns per modelled ray)")


# ------------------------------------------------------------------------------------------------ export (issue 13)
@main.command("export")
@click.argument("store", type=click.Path(path_type=Path))
@click.option("-o", "--output", "out_dir", type=click.Path(path_type=Path), required=True,
              help="Output folder (created; files bakery did not write are never overwritten).")
@click.option("--format", "fmt", required=True,
              help="Export format: ktx2, gltf, three or filament (bakery.export.EXPORT_FORMATS).")
@click.option("--profile", help="Roughness-to-mip profile: gltf, filament, three, babylon (default: the format's).")
@click.option("--probes", "pattern", help="Export only probes whose name matches this glob.")
@click.option("--option", "options", multiple=True, metavar="KEY=VALUE",
              help="Format option, e.g. vk_format=E5B9G9R9_UFLOAT_PACK32, levels=5, layout=array (repeatable).")
@click.option("--layer", type=click.Path(path_type=Path),
              help="Baked USD layer of STORE to reference the files from (default: <store stem>.bake.usda beside the "
                   "store, if present); any other file is refused (exit 2).")
@click.option("--no-layer", is_flag=True, help="Do not touch any USD layer.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
def export_command(store: Path, out_dir: Path, fmt: str, profile: str | None, pattern: str | None,
                   options: tuple[str, ...], layer: Path | None, no_layer: bool, as_json: bool) -> None:
    """Write STORE's probes as files engines load directly (docs/exports.md). Exit 2: bad input (nothing written);
    3: unknown format, profile or option."""
    from bakery.export import export_store
    from bakery.export.base import parse_options

    result = export_store(store, out_dir, fmt, profile=profile, probes=pattern, options=parse_options(options),
                          layer=False if no_layer else layer)
    if as_json:
        _print_json(result.as_dict())
    else:
        console.print(f"{out_dir}: {_count(len(result.files), fmt + ' file')}, profile {result.profile}"
                      + (f"; layer {result.layer}" if result.layer else ""))


def _run_recipe_exports(recipe: str, store: Path, layer: str | None) -> None:
    """The recipe's ``exports`` after a bake: outputs relative to the store's folder."""
    from bakery.export import export_store
    from bakery.pipeline.recipe import load_recipe

    for entry in load_recipe(recipe).exports:
        target = Path(entry["output"])
        target = target if target.is_absolute() else Path(store).parent / target
        result = export_store(store, target, entry["format"], profile=entry.get("profile"),
                              probes=entry.get("probes"), options=entry.get("options", {}),
                              layer=Path(layer) if layer else False)  # no layer baked: touch none
        console.print(f"exported {_count(len(result.files), entry['format'] + ' file')} to {target}")


if __name__ == "__main__":  # pragma: no cover
    main()

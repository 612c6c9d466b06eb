"""The ``prt`` command line. Each command parses its options, calls one entry of
:mod:`pipeline.job`, and prints. Input problems print one line ``error: FILE: PROBLEM``
and exit with status 2."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from pipeline.errors import PrtError
from pipeline.executors import Cores, available_cpus, use_cores

SCENE = click.argument("scene", required=False, type=click.Path(path_type=Path))
WORKDIR = click.option("--workdir", type=click.Path(path_type=Path), default=None,
                       help="Work directory for artifacts [default: ./.prt/<scene name>].")
STAGES = click.option("--stages", "stagefile", type=click.Path(path_type=Path), default=None,
                      help="Stage file [default: the project's stages.yaml].")
QUIET = click.option("--quiet", "-q", is_flag=True, help="No progress bars.")
_AUTO = Cores.auto()
JOBS = click.option(
    "--jobs", "-j", type=click.IntRange(min=1), default=None,
    help=f"Chunks computed at once: worker processes (1: in this process). [default: "
         f"$PRT_JOBS, else with --threads T the cores / T, else chosen for the cores: "
         f"{_AUTO.workers} here ({_AUTO.describe()} on {available_cpus()} cores)]")
THREADS = click.option(
    "--threads", type=click.IntRange(min=1), default=None,
    help=f"Threads per chunk (its thread pools, Embree's ray batches, the OpenCL CPU "
         f"device's threads). [default: $PRT_THREADS, else with --jobs N the cores / N, "
         f"else chosen for the cores: {_AUTO.threads} here]")


def cores_option(jobs: int | None, threads: int | None) -> Cores:
    """The Cores setting of a command's --jobs and --threads (see pipeline/executors.py
    ``Cores.resolve``), applied to this process (its frames use as many threads, and
    PoCL's CPU device no more, when fewer than the cores)."""
    cores = Cores.resolve(jobs, threads)
    use_cores(cores)
    return cores


def parse_size(text: str | None) -> tuple[int, int] | None:
    """'WxH' -> (W, H); PrtError unless both are positive integers."""
    if text is None:
        return None
    w, sep, h = text.lower().partition("x")
    try:
        width, height = int(w), int(h)
    except ValueError:
        width = height = 0
    if not sep or width < 1 or height < 1:
        raise PrtError("--size", f"{text!r}: expected WIDTHxHEIGHT with positive integers")
    return width, height


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="prt-pipeline")
def cli() -> None:
    """Bake precomputed light transport for a scene and render relit frames.

    SCENE is a scene YAML file; it defaults to the embedded Cornell box."""


@cli.command("run")
@SCENE
@click.option("--until", metavar="STAGE", help="Stop after STAGE (and skip rendering).")
@click.option("--force", metavar="STAGE", multiple=True, help="Re-run STAGE even if fresh.")
@click.option("--frames", type=click.Path(path_type=Path), default=None,
              help="Folder for the rendered frames [default: ./frames/<scene name>].")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
@WORKDIR
@STAGES
@JOBS
@THREADS
@QUIET
def run_cmd(scene, until, force, frames, as_json, workdir, stagefile, jobs, threads,
            quiet) -> None:
    """Bake every stale stage, then render the scene's frames."""
    from pipeline import job

    cores = cores_option(jobs, threads)
    sc = job.open_scene(scene)
    wd = job.workdir_for(sc, workdir)
    frames = frames or Path("frames") / sc.name
    report, rendered, sequences = job.main_job(sc, wd, frames, until, tuple(force),
                                               cores.workers, quiet, stagefile,
                                               threads=cores.threads)
    if as_json:
        click.echo(json.dumps({
            "stages": [{"name": r.name, "action": r.action, "ran_chunks": r.ran_chunks,
                        "reused_chunks": r.reused_chunks, "seconds": round(r.seconds, 4),
                        "reason": r.reason} for r in report],
            "frame": None if rendered is None else str(rendered.exr),
            "sequences": {q.kind: [str(p) for p in q.exr] for q in sequences}}))
        return
    ran = [r for r in report if r.action == "ran"]
    for r in report:
        if r.action == "ran":
            reused = f", {len(r.reused_chunks)} reused" if r.reused_chunks else ""
            click.echo(f"  {r.name:<12} ran {len(r.ran_chunks)} chunk(s){reused} in "
                       f"{r.seconds:.2f} s  ({r.reason})")
        else:
            click.echo(f"  {r.name:<12} fresh, skipped")
    if not ran:
        click.echo(f"All {len(report)} stages fresh: nothing to bake.")
    if rendered is not None:
        state = "up to date" if rendered.frame is None else "rendered"
        click.echo(f"Frame {state}: {rendered.exr} (preview {rendered.png})")
    for q in sequences:
        click.echo(f"Sequence {q.kind}: {len(q.exr)} frames {q.exr[0].name} .. "
                   f"{q.exr[-1].name} (EXR + PNG)")


@cli.command("status")
@SCENE
@click.option("--json", "as_json", is_flag=True, help="Print {\"stages\": [...]} as JSON.")
@WORKDIR
@STAGES
def status_cmd(scene, as_json, workdir, stagefile) -> None:
    """Show whether each stage is fresh, stale or missing, and why."""
    from pipeline import job

    sc = job.open_scene(scene)
    plans = job.status(sc, job.workdir_for(sc, workdir), stagefile)
    rows = [{"name": p.spec.name, "state": p.state, "reason": p.reason} for p in plans]
    if as_json:
        click.echo(json.dumps({"stages": rows}))
        return
    for row in rows:
        reason = f"  ({row['reason']})" if row["reason"] else ""
        click.echo(f"  {row['name']:<12} {row['state']}{reason}")


@cli.command("inspect")
@click.argument("path", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
def inspect_cmd(path, as_json) -> None:
    """Describe an artifact: schema, arrays, chunks, storage and statistics."""
    from pipeline import job

    info = job.inspect_artifact(path)
    if as_json:
        click.echo(json.dumps(info))
        return
    click.echo(f"{info['path']}: kind {info['kind']} v{info['schema_version']}, stage "
               f"{info['stage']}, key {str(info['key'])[:12]}")
    for name, a in info["arrays"].items():
        stats = ("" if a["min"] is None else
                 f" min {a['min']:.4g} max {a['max']:.4g} mean {a['mean']:.4g}")
        click.echo(f"  {name:<16} {a['dtype']:<8} {str(tuple(a['shape'])):<18} dims "
                   f"{a['dims']} chunks {tuple(a['chunks'])}"
                   f"{'' if a['pieces'] is None else ' in ' + str(a['pieces']) + ' pieces'} "
                   f"{a['stored_bytes']} B stored "
                   f"(x{a['compression_ratio']}){stats} NaN {a['nan_count']}")


@cli.command("verify")
@SCENE
@click.option("--json", "as_json", is_flag=True,
              help="Print the report as JSON (problems, counts, what cannot be checked).")
@WORKDIR
@QUIET
def verify_cmd(scene, as_json, workdir, quiet) -> None:
    """Read every chunk of every artifact in the work directory and check it: chunk
    checksums, shapes, NaN/Inf, provenance records and chunk markers. Prints one line
    per problem with the command that re-bakes it; exit status 2 if any."""
    from pipeline import job
    from pipeline.verify import rebake_command, verify

    sc = job.open_scene(scene)
    wd = job.workdir_for(sc, workdir)
    report = verify(wd, progress=not quiet)
    args = "".join(f" {a}" for a in ([str(scene)] if scene else [])
                   + (["--workdir", str(workdir)] if workdir else []))

    def command(p) -> str:
        return rebake_command(p).replace("prt run", f"prt run{args}", 1)

    if as_json:
        click.echo(json.dumps({
            "workdir": str(report.root), "ok": report.ok, "artifacts": report.artifacts,
            "arrays": report.arrays, "chunks": report.chunks, "stored_chunks": report.stored,
            "markers": report.markers, "bytes_read": report.bytes_read,
            "problems": [{"artifact": str(p.artifact), "array": p.array, "chunk": p.chunk,
                          "problem": p.problem, "stage": p.stage, "fix": command(p)}
                         for p in report.problems],
            "unchecked": report.unchecked}))
    else:
        for p in report.problems:
            click.echo(f"BAD {p.where()}: {p.problem}; re-bake: {command(p)}")
        for note in report.unchecked:
            click.echo(f"note: {note}")
        click.echo(f"Verified {report.artifacts} artifacts, {report.arrays} arrays, "
                   f"{report.stored} stored chunks ({report.bytes_read / 1e6:.1f} MB) and "
                   f"{report.markers} chunk markers in {report.root}: "
                   + ("all good." if report.ok else f"{len(report.problems)} problem(s) in "
                      f"{len(report.bad_artifacts)} artifact(s)."))
    if not report.ok:
        raise PrtError(report.root, f"{len(report.problems)} problem(s) found by prt verify "
                       f"in {', '.join(p.name for p in report.bad_artifacts)}")


def parse_options(items: tuple[str, ...]) -> dict[str, str]:
    """``("NAME=VALUE", ...)`` -> {NAME: VALUE} (the method parses the values)."""
    out = {}
    for item in items:
        name, eq, value = item.partition("=")
        if not eq or not name:
            raise PrtError("--option", f"{item!r}: expected NAME=VALUE")
        out[name] = value
    return out


@cli.command("methods")
@click.option("--json", "as_json", is_flag=True, help="Print the methods as JSON.")
def methods_cmd(as_json) -> None:
    """List the rendering methods: what each renders and reads, its options."""
    from pipeline.method import registry

    methods = registry()
    if as_json:
        click.echo(json.dumps({name: {
            "description": m.description, "reads": list(m.reads), "reference": m.reference,
            "options": {o.name: {"type": o.type.__name__, "default": o.default,
                                 "help": o.help} for o in m.options},
            "main_sequences": list(m.main_sequences)} for name, m in methods.items()}))
        return
    for name, m in methods.items():
        click.echo(f"{name}: {m.description}")
        click.echo(f"  reads: {', '.join(m.reads)}; reference transport: {m.reference}")
        for o in m.options:
            click.echo(f"  --option {o.name}={o.default!r} ({o.type.__name__}): {o.help}")
        if m.main_sequences:
            click.echo(f"  sequences (--frames), e.g. {', '.join(m.main_sequences)}")


@cli.command("render")
@SCENE
@click.option("--method", default=None, metavar="NAME",
              help="Rendering method (`prt methods` lists them) [default: the scene's "
                   "first method].")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Output EXR (linear); an sRGB PNG preview is written beside it.")
@click.option("--frames", "sequence", metavar="SPEC", default=None,
              help="Also render a sequence of edits beside OUT (OUT_<kind>_0000.exr, ...), "
                   "as the method reads SPEC (d2i: light:N or gamma[:MATERIAL]:N).")
@click.option("--option", "options", metavar="NAME=VALUE", multiple=True,
              help="A run-time option of the method (repeatable; `prt methods` lists "
                   "them, e.g. d2i's max_bounces=4).")
@click.option("--size", metavar="WxH", help="Image size [default: the scene camera's].")
@click.option("--set", "edits", metavar="NAME.KEY=VALUE", multiple=True,
              help="Run-time material edit (repeatable): NAME a material or object, KEY "
                   "gamma, specular or albedo, VALUE a number or r,g,b; gamma must lie in "
                   "the material's baked gamma_range.")
@click.option("--json", "as_json", is_flag=True,
              help="Print one JSON line with timings (ms) and the image size.")
@WORKDIR
@JOBS
@THREADS
@QUIET
def render_cmd(scene, method, out, sequence, options, size, edits, as_json, workdir, jobs,
               threads, quiet) -> None:
    """Render one frame (baking first whatever the method needs), and optionally a
    sequence of edits."""
    from pipeline import job
    from pipeline.method import get_method, scene_methods
    from pipeline.scene_edits import with_material_edits

    cores = cores_option(jobs, threads)
    sc = with_material_edits(job.open_scene(scene, parse_size(size)), list(edits))
    m = get_method(method) if method else scene_methods(sc)[0]
    values = m.option_values(parse_options(options))
    if sequence and m.sequences is None:
        raise PrtError("--frames", f"method {m.name} has no edit sequences")
    wd = job.workdir_for(sc, workdir)
    result = job.render(sc, wd, m.name, out, jobs=cores.workers, quiet=quiet, options=values,
                        threads=cores.threads)
    frame = result.frame
    if sequence:
        seq = job.render_sequence(sc, wd, m.name, sequence, out, values)
        ms = sorted(t["total_ms"] for t in seq.timings)
        click.echo(f"Wrote {len(seq.exr)} {seq.kind} frames {seq.exr[0]} .. {seq.exr[-1]} "
                   f"(median frame {ms[len(ms) // 2]:.1f} ms)", err=as_json)
    if as_json:
        click.echo(json.dumps({"method": m.name, "width": frame.width, "height": frame.height,
                               **{k: round(v, 3) for k, v in frame.timings.items()},
                               "exr": str(result.exr), "png": str(result.png)}))
        return
    for note in frame.notes:
        click.echo(f"note: {note}", err=True)
    t = frame.timings
    click.echo(f"Wrote {result.exr} and {result.png} ({frame.width}x{frame.height}, "
               f"{m.name}; setup {t['setup_ms']:.1f} ms, kernel {t['kernel_ms']:.1f} ms)")


@cli.command("reference")
@SCENE
@click.option("--transport", default="full", show_default=True,
              help="Light transport: direct (all lights, one reflection), env-direct "
                   "(environment only), first-glossy (full BRDF at the first surface, "
                   "Lambertian after: what d2i models), first-glossy-indirect (that less "
                   "its direct part), full.")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Output EXR (linear); a PNG preview and a JSON record go beside it.")
@click.option("--size", metavar="WxH", help="Image size [default: the scene camera's].")
@click.option("--tolerance", type=click.FloatRange(min=0), default=0.01, show_default=True,
              help="Stop when the estimated relative RMSE of the image is below this.")
@click.option("--max-spp", type=click.IntRange(min=1), default=4096, show_default=True,
              help="Stop at this many paths per pixel.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--pixel-filter", type=click.Choice(["center", "box"]), default="center",
              show_default=True,
              help="center: paths through pixel centres (as the methods render); box: "
                   "jittered over the pixel (as Mitsuba's box filter).")
@click.option("--set", "edits", metavar="NAME.KEY=VALUE", multiple=True,
              help="Material edit as for `prt render` (repeatable).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON line of statistics.")
@WORKDIR
@QUIET
def reference_cmd(scene, transport, out, size, tolerance, max_spp, seed, pixel_filter, edits,
                  as_json, workdir, quiet) -> None:
    """Render a converged Monte-Carlo reference image (cached in the work directory)."""
    from pipeline import job
    from pipeline.images import write_exr, write_png
    from pipeline.reference import ReferenceSettings
    from pipeline.scene_edits import with_material_edits

    if out.suffix.lower() != ".exr":
        raise PrtError(out, "output must be an .exr file")
    sc = with_material_edits(job.open_scene(scene, parse_size(size)), list(edits))
    settings = ReferenceSettings(transport=transport, tolerance=tolerance, max_spp=max_spp,
                                 seed=seed, pixel_filter=pixel_filter)
    result = job.reference(sc, job.workdir_for(sc, workdir), settings, quiet=quiet)
    image = result.image
    write_exr(out, image.mean)
    write_png(out.with_suffix(".png"), image.mean)
    stats = {"transport": transport, "spp": image.spp, "estimate": image.estimate,
             "seconds": round(image.seconds, 3), "rays": image.rays,
             "cached": result.cached, "artifact": str(result.artifact), "exr": str(out)}
    out.with_suffix(".json").write_text(json.dumps(stats, indent=1))
    if as_json:
        click.echo(json.dumps(stats))
        return
    state = "cached" if result.cached else f"rendered in {image.seconds:.1f} s"
    click.echo(f"Wrote {out} ({transport}, {image.spp} spp, estimated relative RMSE "
               f"{image.estimate:.4f}; {state})")


@cli.command("evaluate")
@SCENE
@click.option("--method", default=None, metavar="NAME",
              help="Method to evaluate [default: the scene's first method].")
@click.option("--sweep", "sweeps", metavar="NAME=V1,V2,...", multiple=True,
              help="Budget values to sweep (repeatable; several make a grid): size (image "
                   "width, or WxH), a stage parameter such as gather.count, "
                   "truncate.tolerance or brdf_basis.max_k, or render.OPTION (a run-time "
                   "option of the method). [default: the method's own small sweep]")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Folder for results.json, probe.json, the charts and frames.")
@click.option("--repeats", type=click.IntRange(min=1), default=5, show_default=True,
              help="Timed frames per budget (medians are reported).")
@click.option("--reference-max-spp", type=click.IntRange(min=1), default=None,
              help="Sample cap of the reference images [default: the method's, or 4096 "
                   "with --sweep].")
@click.option("--size", metavar="WxH", help="Image size of every budget that does not sweep "
                                            "size [default: the scene camera's].")
@WORKDIR
@QUIET
def evaluate_cmd(scene, method, sweeps, out, repeats, reference_max_spp, size, workdir,
                 quiet) -> None:
    """Chart a method's error against frame time, storage and bake time over budgets."""
    from pipeline import evaluate, job
    from pipeline.method import get_method, scene_methods

    sc = job.open_scene(scene, parse_size(size))
    m = get_method(method) if method else scene_methods(sc)[0]
    sc, sweep, cap = evaluate.default_plan(sc, m, evaluate.parse_sweep(list(sweeps)),
                                           reference_max_spp, size is not None)
    settings = evaluate.EvaluateSettings(repeats, cap)
    records = evaluate.evaluate(sc, job.workdir_for(sc, workdir), m.name, sweep, out,
                                settings, quiet)
    click.echo(f"Wrote {out / 'results.json'} ({len(records)} budgets) and charts "
               f"{', '.join(name for _, _, name in evaluate.CHARTS)}")


@cli.command("clean")
@SCENE
@WORKDIR
def clean_cmd(scene, workdir) -> None:
    """Delete the scene's work directory (all baked artifacts)."""
    from pipeline import job

    sc = job.open_scene(scene)
    wd = job.workdir_for(sc, workdir)
    freed = job.clean(wd)
    click.echo(f"Removed {wd.root} ({freed / 1e6:.1f} MB)")


def main() -> None:
    """Entry point: run the CLI, turning input errors into one line and status 2."""
    try:
        cli.main(standalone_mode=False)
    except PrtError as exc:
        click.echo(f"error: {exc.one_line()}", err=True)
        sys.exit(2)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        click.echo("interrupted; finished chunks are kept", err=True)
        sys.exit(130)

"""The ``prt`` command line. Each command parses its options, calls one entry of
:mod:`pipeline.job`, and prints. Input problems print one line ``error: FILE: PROBLEM``
and exit with status 2."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from pipeline.device.threads import available_cpus
from pipeline.engine.executors.local import Cores, use_cores
from pipeline.errors import PrtError
from pipeline.evaluation import reference_cache
from pipeline.scene.model import MAX_IMAGE_SIDE

SCENE = click.argument("scene", required=False, type=click.Path(path_type=Path))
WORKDIR = click.option("--workdir", type=click.Path(path_type=Path), default=None,
                       help="Work directory for artifacts [default: ./.prt/<scene name>].")
STAGES = click.option("--stages", "stagefile", type=click.Path(path_type=Path), default=None,
                      help="Stage file [default: the project's stages.yaml].")
QUIET = click.option("--quiet", "-q", is_flag=True, help="No progress bars.")
SIZE = click.option("--size", metavar="WxH",
                    help="Image size [default: the scene camera's]. The bake at another "
                         "size than the file's keeps its camera-dependent artifacts apart "
                         "(<workdir>/views/WxH), so it never replaces the file's bake.")
BAKE_DEVICE = click.option(
    "--bake-device", type=click.Choice(["auto", "device", "embree"]), default=None,
    help="Who traces the bake's visibility rays: device (the project's BVH kernel on the "
         "OpenCL device), embree (the host's cores) or auto (the device on a GPU, Embree "
         "on a CPU device, where it is the faster; `prt devices` says which). A stage "
         "parameter, bake.device: bakes on each are kept apart by their keys. [default: "
         "the scene's settings.bake.device, else auto]")
RENDER_SIZE = click.option(
    "--size", metavar="WxH",
    help="Image size [default: the scene camera's]. A method that traces the camera at "
         "run time (triple, sg) renders it from the bake of the file's camera, re-baking "
         "nothing (its limits warn where that bake is too coarse); another bakes its "
         "camera-dependent artifacts for the size apart (<workdir>/views/WxH), never "
         "over the file's bake.")
EXPOSURE = click.option("--exposure", metavar="EV", type=float, default=0.0,
                        show_default=True,
                        help="Exposure of the PNG previews in stops (× 2^EV); the EXR "
                             "frames stay linear and unscaled.")
FRAMES_DIR = "Folder for the rendered frames [default: ./frames/<scene name>]."
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
    """The Cores setting of a command's --jobs and --threads (see pipeline/engine/executors/local.py
    ``Cores.resolve``), applied to this process (its frames use as many threads, and
    the OpenCL CPU device no more, when fewer than the cores)."""
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
    if max(width, height) > MAX_IMAGE_SIDE:
        raise PrtError("--size", f"{text!r}: at most {MAX_IMAGE_SIDE} pixels per side")
    return width, height


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="prt-pipeline")
def cli() -> None:
    """Bake precomputed light transport for a scene and render relit frames.

    SCENE is a scene YAML file; it defaults to the embedded Cornell box."""


@cli.command("run")
@SCENE
@click.option("--until", metavar="STAGE", multiple=True,
              help="Stop after STAGE (and skip rendering); repeatable: after all of them.")
@click.option("--force", metavar="STAGE", multiple=True, help="Re-run STAGE even if fresh.")
@click.option("--frames", type=click.Path(path_type=Path), default=None, help=FRAMES_DIR)
@SIZE
@EXPOSURE
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
@click.option("--dry-run", is_flag=True,
              help="Print what would be baked (per stage: chunks re-run of all, and which "
                   "declared inputs changed for them) and stop; nothing is written.")
@WORKDIR
@STAGES
@JOBS
@THREADS
@click.option("--scheduler", metavar="ADDRESS|local:N", default=None,
              help="Run the chunks on a dask.distributed cluster: the address of a running "
                   "scheduler (workers must see the work directory and the scene's files "
                   "at the same paths, and run this prt), or local:N for N worker "
                   "processes here. --threads is then per chunk [default: 1 on a "
                   "cluster, the cores / N with local:N]. The artifacts are the same "
                   "bytes as an in-process bake. [default: no cluster]")
@BAKE_DEVICE
@QUIET
def run_cmd(scene, until, force, frames, size, exposure, as_json, dry_run, workdir, stagefile,
            jobs, threads, scheduler, bake_device, quiet) -> None:
    """Bake every stale stage, then bring the scene's frame and edit sequences up to
    date (any missing, changed on disk or stale is rendered again)."""
    from pipeline import job
    from pipeline.registry import limit_warnings, scene_methods, scene_notes

    if scheduler is not None and jobs is not None:
        raise PrtError("--jobs", "does not apply with --scheduler (the cluster's workers "
                       "run the chunks; local:N sets their number)")
    if scheduler is not None:
        from pipeline.engine.executors.dask import parse_scheduler

        parse_scheduler(scheduler)
    cores = cores_option(jobs, threads)
    check_exposure(exposure)
    sc = job.open_scene(scene, parse_size(size), bake_device)
    wd = job.workdir_for(sc, workdir, stagefile)
    until = until or None  # () when not given
    if dry_run:
        _dry_run(sc, wd, stagefile, until, force, as_json)
        return
    frames = frames or Path("frames") / sc.name
    notes = [] if until or stagefile else scene_notes(sc, scene_methods(sc))
    show_notes(notes, as_json)
    limits: list[str] = []
    if not (until or stagefile):
        job.check_device()  # no working device: its one error line, not warnings first
        limits = show_warnings([w for m in scene_methods(sc) for w in limit_warnings(m, sc)],
                               as_json)
    report, rendered, sequences = job.main_job(
        sc, wd, frames, until, tuple(force), cores.workers, quiet, stagefile,
        threads=threads if scheduler else cores.threads, exposure=exposure,
        scheduler=scheduler)
    if rendered is not None:
        limits += show_warnings([w for w in [*rendered.warnings,
                                             *(w for q in sequences for w in q.warnings)]
                                 if w not in limits], as_json)
    warnings = limits + job.tolerance_warnings(report)
    if rendered is not None and rendered.frame is not None:
        notes += rendered.frame.notes
        show_notes(rendered.frame.notes, as_json)
    if as_json:
        click.echo(json.dumps({
            "stages": [{"name": r.name, "action": r.action, "ran_chunks": r.ran_chunks,
                        "reused_chunks": r.reused_chunks, "seconds": round(r.seconds, 4),
                        "reason": r.reason, "tolerances": r.tolerances} for r in report],
            "warnings": warnings,
            "frame": None if rendered is None else str(rendered.exr),
            "frame_rendered": rendered is not None and rendered.frame is not None,
            "sequences": {q.kind: [str(p) for p in q.exr] for q in sequences if q.exr},
            "sequences_rendered": [q.kind for q in sequences if q.exr and q.rendered],
            "sequences_skipped": {q.kind: q.skipped for q in sequences if q.skipped},
            "notes": notes}))
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
    for line in warnings[len(limits):]:  # the limits' went to stderr as they came
        click.echo(f"warning: {line}")
    if rendered is not None:
        state = "up to date" if rendered.frame is None else "rendered"
        click.echo(f"Frame {state}: {rendered.exr} (preview {rendered.png})")
    for q in sequences:
        if q.skipped:
            click.echo(f"Sequence {q.kind}: skipped ({q.skipped})")
            continue
        state = "" if q.rendered else "up to date, "
        click.echo(f"Sequence {q.kind}: {state}{len(q.exr)} frames {q.exr[0].name} .. "
                   f"{q.exr[-1].name} (EXR + PNG)")
        if q.rendered and q.description:
            click.echo(f"  {q.description}")


def _dry_run(sc, wd, stagefile, until, force, as_json) -> None:
    """``prt run --dry-run``: the re-bake forecast of the stages the run would bake."""
    from pipeline import job

    if force:
        raise PrtError("--force", "does not combine with --dry-run (a forced stage re-runs "
                       "every chunk)")
    forecast = job.rebake_forecast(sc, wd, stagefile, until)
    if as_json:
        click.echo(json.dumps({"dry_run": [{"name": f.name, "state": f.state,
                                            **_plan_row(f)} for f in forecast]}))
        return
    for f in forecast:
        click.echo(f"  {f.name:<12} fresh" if f.state == "fresh" else
                   f"  {f.name:<12} {f.state}: {_plan_text(f)}")
    pending = [f for f in forecast if f.state != "fresh"]
    click.echo(f"Dry run: {len(pending)} of {len(forecast)} stages would run; nothing was "
               "written." if pending else f"All {len(forecast)} stages fresh: nothing to bake.")


def check_exposure(ev: float) -> None:
    """PrtError unless ``ev`` (stops) is finite and within ±64 stops."""
    if not -64.0 <= ev <= 64.0:
        raise PrtError("--exposure", f"{ev!r}: expected stops between -64 and 64")


def show_warnings(warnings: list[str], as_json: bool) -> list[str]:
    """Print ``warning: ...`` lines on stderr (with ``--json`` they go into the JSON);
    returns ``warnings``."""
    if not as_json:
        for line in warnings:
            click.echo(f"warning: {line}", err=True)
    return warnings


def show_notes(notes: list[str], as_json: bool) -> None:
    """Print ``note: ...`` lines on stderr (with ``--json`` they go into the JSON)."""
    if not as_json:
        for note in notes:
            click.echo(f"note: {note}", err=True)


@cli.command("status")
@SCENE
@click.option("--frames", type=click.Path(path_type=Path), default=None,
              help="Folder of the frames `prt run` writes [default: ./frames/<scene name>].")
@SIZE
@click.option("--json", "as_json", is_flag=True,
              help="Print {\"stages\": [...], \"frames\": [...]} as JSON.")
@WORKDIR
@STAGES
def status_cmd(scene, frames, size, as_json, workdir, stagefile) -> None:
    """Show whether each stage is fresh, stale or missing, and why; for each stage the
    next `prt run` will bake, how many of its chunks re-run and which declared inputs
    changed for them (an upper bound where an input has yet to run); then whether the
    frame and edit sequences `prt run` writes are present, missing or stale."""
    from pipeline import job

    sc = job.open_scene(scene, parse_size(size))
    wd = job.workdir_for(sc, workdir, stagefile)
    plans = job.status(sc, wd, stagefile)
    forecast = {f.name: f for f in job.rebake_forecast(sc, wd, stagefile)}
    rows = [{"name": p.spec.name, "state": p.state, "reason": p.reason,
             **_partial(wd, p.spec.name), "plan": _plan_row(forecast[p.spec.name])}
            for p in plans]
    outputs = [] if stagefile else job.frame_states(
        sc, wd, frames or Path("frames") / sc.name, plans)
    frame_rows = [{"name": o.name, "path": str(o.path), "state": o.state,
                   "reason": o.reason} for o in outputs]
    if as_json:
        click.echo(json.dumps({"stages": rows, "frames": frame_rows}))
        return
    for row in rows:
        reason = f"  ({row['reason']})" if row["reason"] else ""
        partial = row["partial"]
        state = row["state"] if partial is None else \
            f"partial: {partial['done']}/{partial['total']} chunks"
        click.echo(f"  {row['name']:<12} {state}{reason}")
        if row["state"] != "fresh":
            click.echo(f"  {'':<12} -> {_plan_text(forecast[row['name']])}")
    for row in frame_rows:
        reason = f"  ({row['reason']})" if row["reason"] else ""
        click.echo(f"  {row['name']:<16} {row['state']}: {row['path']}{reason}")


def _plan_row(forecast) -> dict:
    """A stage's re-bake forecast for --json: chunks re-run of total and their ids (None:
    every chunk, counted once its inputs are built), the changed key parts with their
    chunk counts, the rule."""
    return {"rerun": forecast.rerun, "total": forecast.total, "chunks": forecast.chunks,
            "reasons": forecast.reasons, "rule": forecast.rule}


def _plan_text(forecast) -> str:
    """'4/16 chunks re-run: scene materials.ball.gamma changed (4)  [rule]'."""
    if forecast.total is None:
        head = f"every chunk re-runs: {', '.join(forecast.reasons)}"
    else:
        reasons = ", ".join(f"{part} ({n})" for part, n in forecast.reasons.items())
        head = f"{forecast.rerun}/{forecast.total} chunks re-run" + \
            (f": {reasons}" if reasons else "")
    return head + (f"  [{forecast.rule}]" if forecast.rule else "")


def _partial(workdir, stage: str) -> dict[str, dict[str, int] | None]:
    """``{"partial": {"done": n, "total": m}}`` for a stage whose artifact a run left
    incomplete, else ``{"partial": None}``."""
    from pipeline import job

    progress = job.chunk_progress(workdir, stage)
    return {"partial": None if progress is None else
            {"done": progress[0], "total": progress[1]}}


@cli.command("inspect")
@click.argument("path", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
def inspect_cmd(path, as_json) -> None:
    """Describe an artifact (PATH a .zarr folder: schema, arrays, chunks, storage and
    statistics) or a whole work directory (PATH a folder of artifacts: each artifact's
    kind, stage, state, chunks, size and tolerance results)."""
    from pipeline import job

    if job.is_workdir(path):
        info = job.inspect_workdir(path)
        click.echo(json.dumps(info) if as_json else "\n".join(_workdir_lines(info)))
        return
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
    for line in _tolerance_lines(info["tolerances"]):
        click.echo(f"  {line}")


def _tolerance_lines(tolerances: list[dict]) -> list[str]:
    """One line per budget a stage chose from a tolerance (pipeline/engine/tolerance.py)."""
    lines = []
    for t in tolerances:
        budget = ", ".join(f"{k} {v}" for k, v in t["budget"].items())
        verdict = "reached" if t["reached"] else \
            "NOT reached" + (f" (capped at {t['limit']})" if t.get("limit") else "")
        lines.append(f"{t['subject']}: {budget}; {t['measure']} {t['achieved']:.3g}, "
                     f"tolerance {t['tolerance']:.3g}: {verdict}")
    return lines


def _size(n: int) -> str:
    """Bytes as B, kB or MB (powers of 1000)."""
    return f"{n} B" if n < 1e3 else f"{n / 1e3:.1f} kB" if n < 1e6 else f"{n / 1e6:.1f} MB"


def _workdir_lines(info: dict) -> list[str]:
    """``prt inspect WORKDIR`` as text: a line per artifact, its tolerance results
    below it, then the warnings."""
    rows = info["artifacts"]
    lines = [f"{info['path']}: {len(rows)} artifacts, "
             f"{info['stored_bytes'] / 1e6:.2f} MB stored"]
    width = max(len(r["artifact"]) for r in rows)
    kinds = max(len(str(r.get("kind"))) for r in rows)
    for r in rows:
        if r["state"] == "unreadable":
            lines.append(f"  {r['artifact']:<{width}}  unreadable: {r['problem']}")
            continue
        chunks = "" if r["chunks"] is None else \
            (f"{r['chunks']} chunk{'s' if r['chunks'] != 1 else ''}"
             if r["state"] == "complete" else f"{r['chunks_done']}/{r['chunks']} chunks")
        seconds = "" if r["seconds"] is None else f"{r['seconds']:.1f} s"
        lines.append(f"  {r['artifact']:<{width}}  {r['kind']:<{kinds}} v{r['schema_version']}"
                     f"  {r['state']:<8} {chunks:<12} {_size(r['stored_bytes']):>9}  "
                     f"{seconds}".rstrip())
        lines += [f"      {line}" for line in _tolerance_lines(r.get("tolerances", []))]
    lines += [f"warning: {w}" for r in rows for w in r["warnings"]]
    return lines


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
    from pipeline.engine.verify import rebake_command, verify

    sc = job.open_scene(scene)
    wd = job.workdir_for(sc, workdir)
    report = verify(wd, progress=not quiet)
    args = "".join(f" {a}" for a in ([str(scene)] if scene else [])
                   + (["--workdir", str(workdir)] if workdir else []))

    def command(p) -> str:
        return rebake_command(p, report.root).replace("prt run", f"prt run{args}", 1)

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
    """List the rendering methods: what each renders and reads, its options, and its
    limits (where its picture breaks down: each warns when a scene meets it)."""
    from pipeline.registry import registry

    methods = registry()
    if as_json:
        click.echo(json.dumps({name: {
            "description": m.description, "reads": list(m.reads_for()),
            "option_reads": [[o, v, list(st)] for o, v, st in m.option_reads],
            "reference": m.reference,
            "options": {o.name: {"type": o.type.__name__, "default": o.default,
                                 "help": o.help} for o in m.options},
            "sequence_forms": list(m.sequence_forms),
            "main_sequences": list(m.main_sequences), "lights": list(m.lights),
            "materials": list(m.materials), "features": list(m.features),
            "edits": list(m.edits), "limits": {limit.name: limit.what for limit in m.limits}}
            for name, m in methods.items()}))
        return
    for name, m in methods.items():
        click.echo(f"{name}: {m.description}")
        click.echo(f"  reads: {', '.join(m.reads_for())}; reference transport: {m.reference}")
        for option, value, stages in m.option_reads:
            click.echo(f"  reads with --option {option}={value}: {', '.join(stages)}")
        click.echo(f"  renders lights: {', '.join(m.lights) or 'none'}; materials: "
                   f"{', '.join(m.materials) or 'none'}; features: "
                   f"{', '.join(m.features) or 'none'}")
        for o in m.options:
            click.echo(f"  --option {o.name}={o.default!r} ({o.type.__name__}): {o.help}")
        if m.sequence_forms:
            runs = f" (prt run writes {', '.join(m.main_sequences)})" if m.main_sequences \
                else ""
            click.echo(f"  sequences (--frames): {', '.join(m.sequence_forms)}{runs}")
        if m.edits:
            click.echo(f"  run-time edits (prt render, prt view): {', '.join(m.edits)}")
        for limit in m.limits:
            click.echo(f"  limit {limit.name}: {limit.what}")


@cli.command("devices")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def devices_cmd(as_json) -> None:
    """List the OpenCL devices: versions, each one's probe, which one is used and why.

    The device is PRT_CL_DEVICE's if set (cpu, gpu or PLATFORM[:INDEX]), else the first
    GPU, else the first CPU implementation (Intel's CPU runtime, then PoCL) that builds
    and runs a probe kernel right; probe results are cached per machine. Exits with
    status 2 when no device works."""
    from pipeline.device import bake_tracer
    from pipeline.device.devices import report

    info = report()
    info["bake_rays"] = bake_tracer.auto_choice()
    if as_json:
        click.echo(json.dumps(info, indent=1))
    else:
        for line in devices_text(info):
            click.echo(line)
    if "error" in info["chosen"]:
        raise PrtError(None, info["chosen"]["error"])


def devices_text(info: dict) -> list[str]:
    """``prt devices``' report (pipeline/device/devices.py ``report``) as lines."""
    lines = [f"CPU: {info['cpu']}"]
    if info["registration"]["note"]:
        lines.append(info["registration"]["note"])
    for d in info["devices"]:
        probe = d["probe"]
        verdict = "passed" if probe["ok"] else f"FAILED: {probe['reason']}"
        lines += [f"{d['implementation']}: {d['device']} ({d['kind']}, {d['compute_units']} "
                  f"compute units) on {d['platform']}",
                  f"  versions: {d['versions']['platform']}; driver {d['versions']['driver']}",
                  f"  probe: {verdict}{' (cached)' if probe['cached'] else ''}"]
    if not info["devices"]:
        lines.append("no OpenCL device found")
    chosen = info["chosen"]
    if "device" in chosen:
        lines.append(f"using: {chosen['implementation']} ({chosen['device']}): "
                     f"{chosen['reason']}")
    lines.append(info["bake_rays"])
    lines.append(f"probe results cached in {info['cache']}")
    return lines


@cli.command("render")
@SCENE
@click.option("--method", default=None, metavar="NAME",
              help="Rendering method (`prt methods` lists them) [default: the scene's "
                   "first method].")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Output EXR (linear); an sRGB PNG preview is written beside it.")
@click.option("--frames", "sequence", metavar="SPEC", default=None,
              help="Also render a sequence of edits beside OUT (OUT_<kind>_0000.exr, ...), "
                   "as the method reads SPEC (d2i: light[:LIGHT]:N, LIGHT an index into "
                   "lights or a quad light's object, moved around a horizontal circle, "
                   "or gamma[:MATERIAL]:N; triple: rotate:N (the map turns about +y), "
                   "orbit:N (the camera circles its look_at) or gamma[:MATERIAL]:N; sg: "
                   "rotate:N or orbit:N; `prt methods` lists them). The path is printed.")
@click.option("--option", "options", metavar="NAME=VALUE", multiple=True,
              help="A run-time option of the method (repeatable; `prt methods` lists "
                   "them, e.g. d2i's max_bounces=4).")
@RENDER_SIZE
@EXPOSURE
@click.option("--set", "edits", metavar="NAME.KEY=VALUE", multiple=True,
              help="Run-time material edit (repeatable): NAME a material or object, KEY "
                   "gamma, specular or albedo, VALUE a number or r,g,b; gamma must lie in "
                   "the material's baked gamma_range.")
@click.option("--move-light", "moves", metavar="INDEX=DX,DY,DZ", multiple=True,
              help="Move light INDEX (an index into lights: a point, spot or quad light) "
                   "by this offset in scene units (repeatable; no re-bake for d2i).")
@click.option("--camera", "camera", metavar="X,Y,Z", default=None,
              help="Move the camera to X,Y,Z, still looking at its look_at point (the "
                   "methods that trace the camera at run time: triple, sg).")
@click.option("--env", "env_file", type=click.Path(path_type=Path), default=None,
              help="Light the scene with this environment map (EXR or HDR, lat-long) "
                   "instead of its environment light's file.")
@click.option("--env-rotate", "env_rotate", type=float, default=None, metavar="DEG",
              help="Turn the environment map to DEG degrees about its axis (the scene's "
                   "axis, +y unless it says; instead of the scene's rotation).")
@click.option("--env-scale", "env_scale", type=float, default=None, metavar="S",
              help="Scale the environment map's radiance by S (>= 0; instead of the "
                   "scene's scale; no re-bake for triple and sg).")
@click.option("--json", "as_json", is_flag=True,
              help="Print one JSON line with timings (ms) and the image size.")
@WORKDIR
@JOBS
@THREADS
@BAKE_DEVICE
@QUIET
def render_cmd(scene, method, out, sequence, options, size, exposure, edits, moves, camera,
               env_file, env_rotate, env_scale, as_json, workdir, jobs, threads,
               bake_device, quiet) -> None:
    """Render one frame (baking first whatever the method needs), and optionally a
    sequence of edits."""
    from pipeline import job
    from pipeline.registry import (
        check_method_scene,
        get_method,
        limit_warnings,
        scene_methods,
        scene_notes,
    )
    from pipeline.scene.edits import with_run_time_edits

    cores = cores_option(jobs, threads)
    check_exposure(exposure)
    file_scene = job.open_scene(scene, bake_device=bake_device)
    opened = file_scene.with_image_size(*parse_size(size)) if size else file_scene
    sc = with_run_time_edits(opened, list(edits), list(moves), camera, env_file, env_rotate,
                             env_scale)
    m = get_method(method) if method else scene_methods(sc)[0]
    # a method that follows the camera at run time renders a moved or resized camera
    # from the bake of the file's (as its orbit sequence does); another bakes for it
    bake_scene = job.bake_scene(m, sc, file_scene)
    values = m.option_values(parse_options(options))
    if sequence and m.sequences is None:
        raise PrtError("--frames", f"method {m.name} has no edit sequences")
    notes = scene_notes(sc, [m])
    resized = job.resize_note(m, sc, bake_scene)
    notes += [resized] if resized else []
    show_notes(notes, as_json)
    job.check_device()  # no working device: its one error line, not warnings first
    limits = show_warnings(limit_warnings(m, sc), as_json)
    wd = job.workdir_for(bake_scene, workdir)
    if out.suffix.lower() != ".exr":
        raise PrtError(out, "output must be an .exr file")
    baked = None
    if sequence or bake_scene is not sc:  # a bad spec fails before any frame
        check_method_scene(m, sc)
        baked = job.bake(bake_scene, wd, jobs=cores.workers, quiet=quiet, methods=[m],
                         threads=cores.threads, options=values)
        if sequence:
            plan = job.plan_sequence(sc, wd, m.name, sequence, out, values)
    renderer_of = job.shared_renderer(sc, wd, m.name, values)  # the frame's and the sequence's
    result = job.render(sc, wd, m.name, out, jobs=cores.workers, quiet=quiet, options=values,
                        threads=cores.threads, exposure=exposure, renderer_of=renderer_of,
                        baked=baked)
    frame = result.frame
    limits += show_warnings([w for w in result.warnings if w not in limits], as_json)
    if sequence:
        seq = job.render_sequence(sc, wd, m.name, sequence, out, values, exposure, plan=plan,
                                  renderer_of=renderer_of)
        limits += show_warnings([w for w in seq.warnings if w not in limits], as_json)
        ms = sorted(t["total_ms"] for t in seq.timings)
        click.echo(f"Wrote {len(seq.exr)} {seq.kind} frames {seq.exr[0]} .. {seq.exr[-1]} "
                   f"(median frame {ms[len(ms) // 2]:.1f} ms)", err=as_json)
        if seq.description:
            click.echo(f"  {seq.description}", err=as_json)
    show_notes(frame.notes, as_json)
    warnings = job.tolerance_warnings(result.baked)
    if as_json:
        warnings = limits + warnings
        click.echo(json.dumps({"method": m.name, "width": frame.width, "height": frame.height,
                               **{k: round(v, 3) for k, v in frame.timings.items()},
                               "exr": str(result.exr), "png": str(result.png),
                               "notes": notes + frame.notes, "warnings": warnings}))
        return
    for line in warnings:
        click.echo(f"warning: {line}", err=True)
    t = frame.timings
    click.echo(f"Wrote {result.exr} and {result.png} ({frame.width}x{frame.height}, "
               f"{m.name}; setup {t['setup_ms']:.1f} ms, kernel {t['kernel_ms']:.1f} ms)")


@cli.command("view")
@SCENE
@click.option("--method", default=None, metavar="NAME",
              help="Rendering method [default: the scene's first method].")
@RENDER_SIZE
@click.option("--port", type=click.IntRange(0, 65535), default=8043, show_default=True,
              help="Port on localhost (0: any free port).")
@click.option("--open", "open_browser", is_flag=True, help="Open the page in a browser.")
@click.option("--exposure", metavar="EV", type=float, default=None,
              help="The page's exposure at start, in stops [default: 0, or the stops "
                   "that make a dark first frame readable, as prt render's note says].")
@click.option("--save-dir", type=click.Path(path_type=Path), default=None,
              help="Where the page's save button writes [default: ./frames/<scene "
                   "name>/view].")
@WORKDIR
@JOBS
@THREADS
@QUIET
def view_cmd(scene, method, size, port, open_browser, exposure, save_dir, workdir, jobs,
             threads, quiet) -> None:
    """Bake what is stale, then relight the scene interactively in the browser: the
    method's run-time edits (lights, environment, camera, materials, options) as
    controls, frames as you drag, a save button writing what `prt render` writes."""
    from pipeline import job
    from pipeline.registry import (
        check_method_scene,
        get_method,
        limit_warnings,
        scene_methods,
        scene_notes,
    )
    from pipeline.view import bind, serve
    from pipeline.view.server import Engine
    from pipeline.view.state import ViewScene, scene_diagonal

    cores = cores_option(jobs, threads)
    if exposure is not None:
        check_exposure(exposure)
    file_scene = job.open_scene(scene)
    sc = file_scene.with_image_size(*parse_size(size)) if size else file_scene
    m = get_method(method) if method else scene_methods(sc)[0]
    check_method_scene(m, sc)
    if not m.renders:
        raise PrtError(None, f"method {m.name} has no renderer yet; nothing to view")
    # as prt render: a method that follows the camera at run time renders --size from
    # the bake of the file's camera (decision 0045)
    bake_scene = job.bake_scene(m, sc, file_scene)
    sock = bind(port)  # a port in use fails before the bake
    try:
        resized = job.resize_note(m, sc, bake_scene)
        notes = scene_notes(sc, [m]) + ([resized] if resized else [])
        show_notes(notes, False)
        job.check_device()
        warnings = show_warnings(limit_warnings(m, sc), False)
        wd = job.workdir_for(bake_scene, workdir)
        baked = job.bake(bake_scene, wd, jobs=cores.workers, quiet=quiet, methods=[m],
                         threads=cores.threads)
        warnings += show_warnings(job.tolerance_warnings(baked), False)
        # the limits on the frame as rendered, with the artifacts (a size larger than
        # baked: triple's texels per pixel), each once, in the console and the page
        warnings += show_warnings([w for w in limit_warnings(m, sc, job.method_artifacts(
            m, wd)) if w not in warnings], False)
        view = ViewScene(sc, m, None if scene is None else str(scene), size,
                         scene_diagonal(wd.artifact("geometry"), sc),
                         None if workdir is None else str(workdir))
        engine = Engine(view, wd)
        engine.notices = [f"note: {n}" for n in notes] + [f"warning: {w}" for w in warnings]
        from pipeline.images import readable_exposure
        from pipeline.view.encode import encode

        first = engine.frame({})[1]
        encode(first, "jpeg")  # renderer, first frame and encoder warm
        engine.exposure = exposure if exposure is not None else \
            float(readable_exposure(first) or 0)
        if m.drag_options:  # and the drag's renderer, so that the first drag is not slow
            engine.frame({}, dragging=True)
        folder = save_dir or Path("frames") / sc.name / "view"

        def ready(url: str) -> None:
            click.echo(f"Viewing {sc.name} with method {m.name} at {url} (Ctrl-C stops)")
            sys.stdout.flush()
            if open_browser:
                import webbrowser

                webbrowser.open(url)

        serve(engine, sock, folder, ready)
    finally:
        sock.close()
    click.echo("Stopped; the work directory was only read.")


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
@click.option("--lobe", type=click.Choice(["all", "glossy", "diffuse"]), default="all",
              show_default=True,
              help="The part of the BRDF at the first surface a camera ray meets: all, "
                   "glossy only, or diffuse only (glossy + diffuse = all less the light "
                   "the camera sees directly).")
@click.option("--set", "edits", metavar="NAME.KEY=VALUE", multiple=True,
              help="Material edit as for `prt render` (repeatable).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON line of statistics.")
@WORKDIR
@QUIET
def reference_cmd(scene, transport, out, size, tolerance, max_spp, seed, pixel_filter, lobe,
                  edits, as_json, workdir, quiet) -> None:
    """Render a converged Monte-Carlo reference image (cached in the work directory)."""
    from pipeline import job
    from pipeline.evaluation.reference import ReferenceSettings
    from pipeline.images import check_writable, write_exr, write_png
    from pipeline.scene.edits import with_material_edits

    if out.suffix.lower() != ".exr":
        raise PrtError(out, "output must be an .exr file")
    sc = with_material_edits(job.open_scene(scene, parse_size(size)), list(edits))
    check_writable(out)
    settings = ReferenceSettings(transport=transport, tolerance=tolerance, max_spp=max_spp,
                                 seed=seed, pixel_filter=pixel_filter, lobe=lobe)
    result = reference_cache.reference(sc, job.workdir_for(sc, workdir), settings, quiet=quiet)
    image = result.image
    write_exr(out, image.mean)
    write_png(out.with_suffix(".png"), image.mean)
    stats = {"transport": transport, "lobe": lobe, "spp": image.spp, "estimate": image.estimate,
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
    from pipeline import job
    from pipeline.evaluation import evaluate
    from pipeline.evaluation.charts import CHARTS
    from pipeline.registry import get_method, scene_methods

    sc = job.open_scene(scene, parse_size(size))
    m = get_method(method) if method else scene_methods(sc)[0]
    sc, sweep, cap = evaluate.default_plan(sc, m, evaluate.parse_sweep(list(sweeps)),
                                           reference_max_spp, size is not None)
    settings = evaluate.EvaluateSettings(repeats, cap)
    records = evaluate.evaluate(sc, job.workdir_for(sc, workdir), m.name, sweep, out,
                                settings, quiet)
    for line in evaluate.summary_lines(records):  # also with --quiet: it is the result
        click.echo(line)
    click.echo(f"Wrote {out / 'results.json'} ({len(records)} budgets) and charts "
               f"{', '.join(name for _, _, name in CHARTS)}")


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

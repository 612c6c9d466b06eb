"""Fault injection: flip one random byte in one random chunk file of the default scene's
work directory, many times, and see who notices; then what the chunk checksums cost.

Run from the project root:  python studies/fault_injection.py [--size 96] [--trials 200]

1. Bakes the embedded Cornell box (the default scene) at SIZE x SIZE pixels into
   WORKDIR (kept between runs: a fresh bake is reused) and renders the baseline main
   frame of the scene's first method (d2i).
2. Each trial (seeded) picks one chunk file of any artifact uniformly, and one byte of
   it uniformly, XORs it with a random non-zero value, then: runs ``prt verify``'s check
   (pipeline/engine/verify.py, in this process) and, separately, the next ``prt render`` of the
   main frame (``job.render``: plans the bake, then renders). The render is classified
   as *detected* (PrtError), *crashed* (any other exception), *silently changed* (it
   succeeded and the frame differs bit-wise from the baseline: the goal is 0) or *no
   effect* (the same frame: the byte is in an artifact or part the frame does not
   read). The file is restored (bytes and mtime) after each trial.
3. Read cost of the checksums: every array of every artifact is copied into a second
   tree re-encoded with zstd's checksum off (same level, same chunks), and a third with
   the checksum off and zarr's crc32c codec after zstd instead (a CRC of the compressed
   bytes, the other option the issue names); every chunk of each tree is read
   (``array[...]``, as renderers read), in interleaved repeats (the order rotated each
   repeat). Reported, in wall and in CPU seconds: median times and the median of the
   per-repeat ratios to the tree without checksums, plus the same for decoding alone
   (the chunk bytes in memory: no file system, no zarr).

Writes benchmarks/results/fault_injection.json. The machine may be shared with other
work: timings are medians of interleaved repeats and the load average is recorded.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from pipeline import job
from pipeline.engine.store import Workdir
from pipeline.engine.verify import find_artifacts, verify
from pipeline.errors import PrtError
from pipeline.registry import scene_methods

ROOT = Path(__file__).resolve().parent.parent


def chunk_files(root: Path) -> list[Path]:
    """Every stored chunk file of every artifact under ``root`` (zarr v3: ``.../c/...``)."""
    return sorted(p for a in find_artifacts(root) for p in a.rglob("*")
                  if p.is_file() and "/c/" in p.relative_to(a).as_posix())


def render(scene: Any, wd: Workdir, method: str, out: Path) -> np.ndarray:
    """The main frame as ``prt render`` makes it (plan the bake, render, check, write)."""
    return job.render(scene, wd, method, out, jobs=1, quiet=True).frame.rgb


def trial(rng: random.Random, files: list[Path], root: Path, scene: Any, wd: Workdir,
          method: str, baseline: np.ndarray, out: Path) -> dict[str, Any]:
    """One flipped byte: what verify and the next render made of it."""
    file = rng.choice(files)
    original, stat = file.read_bytes(), file.stat()
    offset, mask = rng.randrange(len(original)), rng.randrange(1, 256)
    damaged = bytearray(original)
    damaged[offset] ^= mask
    file.write_bytes(bytes(damaged))
    try:
        report = verify(wd, progress=False)
        named = any(p.array is not None and p.chunk is not None and
                    p.artifact / p.array / "c" / p.chunk.replace(",", "/") == file
                    for p in report.problems)
        try:
            rgb = render(scene, wd, method, out)
            outcome = "no effect" if np.array_equal(rgb, baseline) else "silently changed"
            message = None
        except PrtError as exc:
            outcome, message = "detected", exc.one_line()
        except Exception as exc:  # a crash is a failure to detect cleanly; count it
            outcome, message = "crashed", f"{type(exc).__name__}: {exc}"
    finally:
        file.write_bytes(original)
        os.utime(file, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    return {"file": file.relative_to(root).as_posix(), "bytes": len(original),
            "offset": offset, "xor": mask, "verify_detected": not report.ok,
            "verify_named_the_chunk": named, "verify_problems": len(report.problems),
            "render": outcome, "render_message": message}


# ------------------------------------------------------------------- checksum read cost


def zarr_arrays(root: Path) -> list[Any]:
    """Every zarr array (segment pieces included) of every artifact under ``root``."""
    import zarr

    out = []
    for path in find_artifacts(root):
        group = zarr.open_group(store=str(path), mode="r", zarr_format=3)
        out.extend(a for _, a in group.members(max_depth=None) if isinstance(a, zarr.Array))
    return out


VARIANTS = ("zstd checksum", "none", "crc32c codec")  # as stored by prt, and two copies


def compressors_for(variant: str, level: int) -> list[Any]:
    """The codecs of a variant: zstd with its frame checksum (what prt stores), zstd
    without, or zstd without followed by zarr's crc32c codec (a CRC of the compressed
    bytes, appended)."""
    from zarr.codecs import Crc32cCodec, ZstdCodec

    return {"zstd checksum": [ZstdCodec(level=level, checksum=True)],
            "none": [ZstdCodec(level=level, checksum=False)],
            "crc32c codec": [ZstdCodec(level=level, checksum=False), Crc32cCodec()]}[variant]


def copy_encoded(src: Path, dst: Path, variant: str) -> None:
    """Re-encode every artifact under ``src`` into ``dst`` with the variant's codecs."""
    import zarr
    from zarr.codecs import ZstdCodec

    for path in find_artifacts(src):
        source = zarr.open_group(store=str(path), mode="r", zarr_format=3)
        target = zarr.open_group(store=str(dst / path.relative_to(src)), mode="w",
                                 zarr_format=3)
        for name, node in source.members(max_depth=None):
            if isinstance(node, zarr.Group):
                target.create_group(name)
                continue
            codec = next(c for c in node.metadata.codecs if isinstance(c, ZstdCodec))
            copy = target.create_array(name, shape=node.shape, dtype=node.dtype,
                                       chunks=node.chunks, fill_value=node.fill_value,
                                       compressors=compressors_for(variant, codec.level),
                                       dimension_names=node.metadata.dimension_names)
            if node.size:
                copy[...] = node[...]


def read_everything(arrays: list[Any]) -> tuple[float, float]:
    """Wall and CPU seconds (all threads) to read every chunk of every array."""
    wall, cpu = time.perf_counter(), time.process_time()
    for arr in arrays:
        arr[...]
    return time.perf_counter() - wall, time.process_time() - cpu


def decode_everything(frames: list[bytes], crc: bool) -> tuple[float, float]:
    """Wall and CPU seconds to decode chunk files in memory: zstd (which checks its
    frame checksum when the frame has one), after checking the trailing CRC32C first
    when ``crc``."""
    import google_crc32c
    from numcodecs import Zstd

    codec = Zstd()
    wall, cpu = time.perf_counter(), time.process_time()
    for frame in frames:
        if crc:
            assert google_crc32c.value(frame[:-4]).to_bytes(4, "little") == frame[-4:]
            frame = frame[:-4]
        codec.decode(frame)
    return time.perf_counter() - wall, time.process_time() - cpu


def interleaved(runs: dict[str, Any], repeats: int, baseline: str) -> dict[str, Any]:
    """Time each of ``runs`` (name -> function giving (wall, CPU) seconds) once per
    repeat, the order rotated each repeat: per clock, each one's median and the median
    (and quartiles) of its per-repeat ratio to ``baseline``. CPU time (this process's
    threads) is less disturbed by other jobs on a shared machine than wall time."""
    names = list(runs)
    times: dict[str, list[tuple[float, float]]] = {n: [] for n in names}
    for n in names:
        runs[n]()  # warm-up: page cache, imports, thread pools
    for r in range(repeats):
        for n in names[r % len(names):] + names[:r % len(names)]:
            times[n].append(runs[n]())
    out: dict[str, Any] = {"repeats": repeats, "baseline": baseline}
    for clock, i in (("wall", 0), ("cpu", 1)):
        out[clock] = {}
        for n in names:
            entry = {"s_median": round(statistics.median(t[i] for t in times[n]), 4)}
            if n != baseline:
                ratios = [t[i] / b[i] for t, b in zip(times[n], times[baseline], strict=True)]
                entry |= {"ratio_median": round(statistics.median(ratios), 4),
                          "ratio_quartiles": [round(q, 4) for q in
                                              statistics.quantiles(ratios, n=4)[::2]]}
            out[clock][n] = entry
    return out


def checksum_cost(root: Path, repeats: int) -> dict[str, Any]:
    """Read and decode cost of the stored checksums against copies without (and with
    zarr's crc32c codec instead)."""
    with tempfile.TemporaryDirectory(dir=root.parent) as tmp:
        roots = {"zstd checksum": root}
        for variant in VARIANTS[1:]:
            roots[variant] = Path(tmp) / variant.replace(" ", "_")
            copy_encoded(root, roots[variant], variant)
        arrays = {v: zarr_arrays(r) for v, r in roots.items()}
        files = {v: chunk_files(r) for v, r in roots.items()}
        assert len({len(f) for f in files.values()}) == 1, "a copy stores other chunks"
        frames = {v: [p.read_bytes() for p in f] for v, f in files.items()}
        read = interleaved({v: (lambda a=a: read_everything(a)) for v, a in arrays.items()},
                           repeats, "none")
        decode = interleaved({v: (lambda f=f, v=v: decode_everything(f, v == "crc32c codec"))
                              for v, f in frames.items()}, repeats, "none")
    return {"chunk_files": len(files["none"]),
            "stored_bytes": {v: sum(map(len, f)) for v, f in frames.items()},
            "read_every_chunk_via_zarr": read, "zstd_decode_only": decode}


# ------------------------------------------------------------------------------- main


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=96, help="image width = height")
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--seed", type=int, default=15)
    parser.add_argument("--repeats", type=int, default=31, help="timing repeats")
    parser.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir())
                        / "prt-fault-injection", help="where the bake is kept")
    parser.add_argument("--out", type=Path,
                        default=ROOT / "benchmarks" / "results" / "fault_injection.json")
    args = parser.parse_args()

    scene = job.open_scene(None, (args.size, args.size))
    wd = Workdir(args.workdir / f"{scene.name}_{args.size}")
    load = [os.getloadavg()]
    start = time.perf_counter()
    job.bake(scene, wd, quiet=True)
    bake_s = time.perf_counter() - start
    method = scene_methods(scene)[0].name
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "frame.exr"
        baseline = render(scene, wd, method, out)
        deterministic = bool(np.array_equal(baseline, render(scene, wd, method, out)))
        start = time.perf_counter()
        clean = verify(wd, progress=False)
        verify_s = time.perf_counter() - start
        assert clean.ok, [p.where() for p in clean.problems]
        files = chunk_files(wd.root)
        rng = random.Random(args.seed)
        trials = []
        start = time.perf_counter()
        for i in range(args.trials):
            trials.append(trial(rng, files, wd.root, scene, wd, method, baseline, out))
            t = trials[-1]
            print(f"{i + 1:4d}/{args.trials} {t['file']} @{t['offset']}: verify "
                  f"{'detected' if t['verify_detected'] else 'MISSED'}, render "
                  f"{t['render']}", flush=True)
        trials_s = time.perf_counter() - start
    assert verify(wd, progress=False).ok, "a trial did not restore its file"
    load.append(os.getloadavg())
    cost = checksum_cost(wd.root, args.repeats)
    load.append(os.getloadavg())
    by_artifact: dict[str, Counter] = {}
    for t in trials:
        by_artifact.setdefault(t["file"].split("/")[0], Counter())[t["render"]] += 1
    result = {
        "what": "one random byte XOR a random non-zero value in one random chunk file, "
                "restored after each trial; verify = pipeline.engine.verify.verify (prt verify); "
                "render = job.render of the main frame (prt render)",
        "scene": f"cornell_box (embedded default), {args.size}x{args.size}, method {method}",
        "machine": {"python": platform.python_version(), "cores": os.cpu_count(),
                    "load_average_1_5_15": [[round(x, 2) for x in la] for la in load],
                    "note": "shared with other jobs while measured: timings are medians of "
                            "interleaved repeats and still noisy"},
        "seed": args.seed, "trials": args.trials, "chunk_files": len(files),
        "bake_s": round(bake_s, 1), "verify_clean_s": round(verify_s, 2),
        "verify_clean": {"artifacts": clean.artifacts, "arrays": clean.arrays,
                         "chunks": clean.chunks, "stored_chunks": clean.stored,
                         "bytes_read": clean.bytes_read, "unchecked": clean.unchecked},
        "render_is_deterministic": deterministic, "trials_s": round(trials_s, 1),
        "counts": {
            "verify_detected": sum(t["verify_detected"] for t in trials),
            "verify_named_the_flipped_chunk": sum(t["verify_named_the_chunk"] for t in trials),
            "render_detected": sum(t["render"] == "detected" for t in trials),
            "render_crashed": sum(t["render"] == "crashed" for t in trials),
            "render_silently_changed_frame": sum(t["render"] == "silently changed"
                                                 for t in trials),
            "render_no_effect": sum(t["render"] == "no effect" for t in trials)},
        "render_by_artifact": {k: dict(v) for k, v in sorted(by_artifact.items())},
        "checksum_read_cost": cost,
        "trial_log": trials,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({k: result[k] for k in ("scene", "counts", "render_by_artifact")}
                     | {"checksum_read_cost": cost}, indent=1))


if __name__ == "__main__":
    main()

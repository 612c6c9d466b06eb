"""Stored chunks are checksummed: a byte changed on disk in any chunk of any artifact
kind is an error naming the artifact and chunk, never numbers read as if nothing
happened."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import D2I_STAGES, small_scene_dict, write_scene

from pipeline import job
from pipeline.engine.store import Workdir, open_artifact, read_record
from pipeline.errors import PrtError
from pipeline.scene.file import load_scene


@pytest.fixture(scope="module")
def baked(tmp_path_factory) -> tuple[Path, Workdir]:
    """A tiny d2i bake (every artifact kind of the method and the shared stages): the
    scene file and the work directory."""
    folder = tmp_path_factory.mktemp("integrity")
    doc = small_scene_dict(size=16)
    doc["methods"] = ["d2i"]
    doc["settings"] = {"gather.count": 256}
    scene = write_scene(folder, doc)
    workdir = Workdir(folder / "w")
    job.bake(load_scene(scene), workdir, quiet=True)
    return scene, workdir


def prt(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


def damaged_copy(baked: tuple[Path, Workdir], tmp_path: Path, stage: str) -> tuple[Path, Path]:
    """A copy of the bake with one byte flipped in the middle of the stage's largest
    chunk file: (work directory, chunk file)."""
    root = tmp_path / "w"
    shutil.copytree(baked[1].root, root)
    chunk = max((p for p in (root / f"{stage}.zarr").rglob("*")
                 if p.is_file() and "/c/" in p.as_posix()), key=lambda p: p.stat().st_size)
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0x10
    chunk.write_bytes(bytes(data))
    return root, chunk


def snapshot(root: Path) -> dict[Path, tuple[bytes, int]]:
    """Every file under ``root``: its bytes and modification time (ns)."""
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()}


@pytest.mark.parametrize("stage", D2I_STAGES)
def test_a_flipped_byte_in_any_chunk_is_reported(baked, tmp_path, stage):
    """Flip one byte in the middle of the stage's largest chunk file: reading the
    artifact raises PrtError naming the artifact's chunk file and the re-bake command."""
    root, _ = damaged_copy(baked, tmp_path, stage)
    artifact = root / f"{stage}.zarr"
    with pytest.raises(PrtError, match="corrupt or truncated chunk") as error:
        open_artifact(artifact).read_all()
    assert str(artifact) in error.value.one_line() and "prt run --force" in error.value.one_line()


@pytest.mark.parametrize("stage", D2I_STAGES)
def test_verify_finds_a_flipped_byte_and_touches_nothing(baked, tmp_path, stage):
    """`prt verify` on the damaged copy exits 2 with one BAD line naming the artifact,
    its array and chunk index, and `prt run --force STAGE`; neither verifying nor reading
    the damaged artifact changes any file of the work directory (bytes or mtime)."""
    root, chunk = damaged_copy(baked, tmp_path, stage)
    before = snapshot(root)
    result = prt("verify", "--workdir", root, "-q")
    assert result.returncode == 2, result.stdout + result.stderr
    bad = [line for line in result.stdout.splitlines() if line.startswith("BAD ")]
    relative = chunk.relative_to(root / f"{stage}.zarr").as_posix()  # ARRAY/c/I/J
    array, _, index = relative.rpartition("/c/")
    assert len(bad) == 1  # what zstd says differs by where the byte fell
    assert bad[0].startswith(f"BAD {root / f'{stage}.zarr'}, array {array}, chunk "
                             f"{index.replace('/', ',')}: corrupt or truncated chunk (")
    assert bad[0].endswith(f"); re-bake: prt run --workdir {root} --force {stage}")
    assert result.stderr.strip().splitlines() == [
        f"error: {root}: 1 problem(s) found by prt verify in {stage}.zarr"]
    with pytest.raises(PrtError):
        open_artifact(root / f"{stage}.zarr").read_all()
    assert snapshot(root) == before


def test_verify_passes_a_clean_bake(baked):
    """A freshly baked work directory verifies: exit 0, every chunk marker checked, and
    the notes say what a checksum cannot vouch for; no file changes."""
    root = baked[1].root
    before = snapshot(root)
    result = prt("verify", "--workdir", root, "--json", "-q")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["ok"] and report["problems"] == [] and report["artifacts"] == len(D2I_STAGES)
    records = {stage: read_record(root / f"{stage}.zarr") for stage in D2I_STAGES}
    assert report["markers"] == sum(len(r["chunks"]) for r in records.values())
    assert report["stored_chunks"] > 0 and any("zarr.json" in n for n in report["unchecked"])
    assert snapshot(root) == before


def test_verify_reports_markers_records_and_nan(baked, tmp_path):
    """Beyond checksums: a deleted chunk marker, an artifact left incomplete by an
    interrupted run, and a chunk holding NaN written with a valid checksum (so only the
    finiteness check can see it) are each one problem with the command that re-bakes (or, for the
    interrupted run, resumes) it."""
    import zarr

    from pipeline.engine import chunkwrite
    from pipeline.engine.verify import rebake_command, verify

    root = tmp_path / "w"
    shutil.copytree(baked[1].root, root)
    wd = Workdir(root)
    record = read_record(wd.artifact("gbuffer"))
    wd.marker("gbuffer", record["chunks"][0]).unlink()
    incomplete = read_record(wd.artifact("d2i.bounce"))
    chunkwrite.restore_record(wd.artifact("d2i.bounce"), {**incomplete, "complete": False})
    depth = zarr.open_group(str(wd.artifact("gbuffer")), mode="r+")["depth"]
    depth[0, 0] = np.nan
    report = verify(wd, progress=False)
    found = {(p.artifact.name, p.array, p.chunk, p.problem.split(" (")[0]): rebake_command(p, root)
             for p in report.problems}
    assert found == {
        ("gbuffer.zarr", None, record["chunks"][0], "marker missing or unreadable"):
            "prt run --force gbuffer",
        ("d2i.bounce.zarr", None, None, "incomplete: a run was interrupted while writing it"):
            "prt run",
        ("gbuffer.zarr", "depth", "0,0", "1 NaN or Inf values"): "prt run --force gbuffer"}


def test_verify_refuses_while_a_run_writes(baked):
    """A run holding the work directory's lock makes verify refuse (its chunks would
    read as corrupt half-way through a write), naming the work directory."""
    from pipeline.engine.verify import verify

    with baked[1].lock(), pytest.raises(PrtError, match="a prt run is writing"):
        verify(baked[1], progress=False)


def test_render_of_a_damaged_artifact_fails_and_touches_nothing(baked, tmp_path):
    """`prt render` from a work directory with a flipped byte in an artifact its frame
    reads: one error line naming the chunk, exit 2, no frame written, and no file of the
    work directory changed."""
    root, chunk = damaged_copy(baked, tmp_path, "d2i.truncate")
    before = snapshot(root)
    out = tmp_path / "frame.exr"
    result = prt("render", baked[0], "--workdir", root, "--out", out, "-q", "--jobs", "1")
    assert result.returncode == 2, result.stderr
    line = result.stderr.strip()
    assert "\n" not in line and line.startswith(f"error: {root / 'd2i.truncate.zarr'}")
    assert "corrupt or truncated chunk" in line and "prt run --force d2i.truncate" in line
    assert not out.exists() and snapshot(root) == before


@pytest.mark.parametrize(("texel", "problem"), [(np.nan, "not finite"), (np.inf, "not finite"),
                                                (-1.0, "negative")])
def test_a_bad_environment_map_is_refused(tmp_path, texel, problem):
    """`prt reference --transport env-direct` with a map holding a NaN, Inf or negative
    texel exits 2 with one line naming the map and the texel, not a half-NaN image."""
    from helpers import constant_environment

    from pipeline.images import write_exr

    env = constant_environment(tmp_path / "env.exr", [1.0, 1.0, 1.0])
    rgb = np.ones((8, 16, 3), np.float32)
    rgb[3, 5, 1] = texel
    write_exr(env, rgb)
    doc = small_scene_dict(size=8)
    doc["lights"] = [{"type": "environment", "file": env.name}]
    scene = write_scene(tmp_path, doc)
    result = subprocess.run([sys.executable, "-m", "pipeline", "reference", str(scene),
                             "--transport", "env-direct", "--out", str(tmp_path / "r.exr"),
                             "--workdir", str(tmp_path / "w"), "--max-spp", "4", "-q"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    line = result.stderr.strip()
    assert "\n" not in line and "Traceback" not in line
    assert str(env) in line and f"(x 5, y 3) is {problem}" in line
    assert not (tmp_path / "r.exr").exists()


def test_the_printed_command_repairs_the_damage(baked, tmp_path):
    """Running the command `prt verify` prints for a damaged chunk re-bakes the stage,
    after which the work directory verifies clean (exit 0)."""
    root, _ = damaged_copy(baked, tmp_path, "d2i.truncate")
    first = prt("verify", baked[0], "--workdir", root, "-q")
    assert first.returncode == 2, first.stderr
    [line] = [line for line in first.stdout.splitlines() if line.startswith("BAD ")]
    command = line.rpartition("; re-bake: ")[2].split()
    assert command == ["prt", "run", str(baked[0]), "--workdir", str(root), "--force",
                       "d2i.truncate"]
    rebake = prt(*command[1:], "--frames", tmp_path / "frames", "-q", "--jobs", "1")
    assert rebake.returncode == 0, rebake.stderr
    again = prt("verify", baked[0], "--workdir", root, "-q")
    assert again.returncode == 0 and "all good" in again.stdout, again.stdout + again.stderr


def test_rebake_command_of_a_view_names_its_size(tmp_path):
    """An artifact baked for another image size (WORKDIR/views/WxH/) is re-baked with
    that --size; one of the file's own size without it."""
    from pipeline.engine.verify import Problem, rebake_command

    view = Problem(tmp_path / "views" / "32x16" / "gbuffer.zarr", "depth", "0,0", "bad",
                   "gbuffer")
    assert rebake_command(view, tmp_path) == "prt run --size 32x16 --force gbuffer"
    own = Problem(tmp_path / "gbuffer.zarr", "depth", "0,0", "bad", "gbuffer")
    assert rebake_command(own, tmp_path) == "prt run --force gbuffer"


def test_a_chunk_for_an_array_the_begun_artifact_lacks_is_refused_by_name(tmp_path):
    """An artifact begun under a schema whose version is the same but whose arrays are
    not (a schema edited without a version bump) is refused when a chunk writes an array
    it lacks: a one-line error naming the array and the fix, not zarr's KeyError."""
    import dataclasses

    from pipeline.engine import chunkwrite
    from pipeline.engine.schema import load_schema

    schema = load_schema("compressed_bounce")
    older = dataclasses.replace(schema, arrays={k: v for k, v in schema.arrays.items()
                                                if k != "ms_row"})
    workdir = Workdir(tmp_path / "w")
    path = workdir.artifact("d2i.truncate_ms")
    chunkwrite.begin(workdir, path, older, {"key": "k", "chunks": ["b0"]}, {}, {})
    rows = {"ms_row": np.zeros(1, np.int32), "ms_count": np.zeros(1, np.int32),
            "ms_index": np.zeros(0, np.int32), "ms_value": np.zeros(0, np.float16),
            "ms_scale": np.ones(1, np.float32)}
    with pytest.raises(PrtError, match="has no array 'ms_row' of schema compressed_bounce"):
        chunkwrite.write_chunk(path, schema, "b0", rows, {"row_chunk": 64,
                                                           "coefficient_chunk": 64})

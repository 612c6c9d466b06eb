"""Stored chunks are checksummed: a byte changed on disk in any chunk of any artifact
kind is an error naming the artifact and chunk, never numbers read as if nothing
happened."""

from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest
from helpers import small_scene_dict, write_scene

from pipeline import job
from pipeline.errors import PrtError
from pipeline.scene import load_scene
from pipeline.store import Workdir, open_artifact

STAGES = ("geometry", "brdf_basis", "gbuffer", "d2i.gather", "d2i.transfer", "d2i.bounce",
          "d2i.truncate")


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """A tiny d2i bake (every artifact kind of the method and the shared stages)."""
    folder = tmp_path_factory.mktemp("integrity")
    doc = small_scene_dict(size=16)
    doc["methods"] = ["d2i"]
    doc["settings"] = {"gather.count": 256}
    workdir = Workdir(folder / "w")
    job.bake(load_scene(write_scene(folder, doc)), workdir, quiet=True)
    return workdir


@pytest.mark.parametrize("stage", STAGES)
def test_a_flipped_byte_in_any_chunk_is_reported(baked, tmp_path, stage):
    """Flip one byte in the middle of the stage's largest chunk file: reading the
    artifact raises PrtError naming the artifact's chunk file and the re-bake command."""
    root = tmp_path / "w"
    shutil.copytree(baked.root, root)
    artifact = root / f"{stage}.zarr"
    chunk = max((p for p in artifact.rglob("*") if p.is_file() and "/c/" in p.as_posix()),
                key=lambda p: p.stat().st_size)
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0x10
    chunk.write_bytes(bytes(data))
    with pytest.raises(PrtError, match="corrupt or truncated chunk") as error:
        open_artifact(artifact).read_all()
    assert str(artifact) in error.value.one_line() and "prt run --force" in error.value.one_line()


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

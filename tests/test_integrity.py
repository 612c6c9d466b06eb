"""Stored chunks are checksummed: a byte changed on disk in any chunk of any artifact
kind is an error naming the artifact and chunk, never numbers read as if nothing
happened."""

from __future__ import annotations

import shutil

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

"""Bad input: each case gives one ``error: FILE: PROBLEM`` line, exit 2, no traceback, and
loses no previously baked artifact.

A module fixture bakes a 32x32 Cornell box once; every test runs ``python -m pipeline`` in a
subprocess against its own copy of that work directory.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

PROJECT = Path(__file__).resolve().parent.parent
SCENES = PROJECT / "scenes"
SIZE = 32


# --------------------------------------------------------------------------- helpers


def prt(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run ``python -m pipeline ARGS`` in ``cwd`` and capture its output."""
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=cwd,
                          env=dict(os.environ), capture_output=True, text=True, timeout=300)


def snapshot(workdir: Path) -> dict[str, str]:
    """sha256 per file of every baked artifact (``*.zarr``) and cached chunk (``.chunks``)."""
    roots = [*sorted(workdir.glob("*.zarr")), workdir / ".chunks"]
    return {str(p.relative_to(workdir)): hashlib.sha256(p.read_bytes()).hexdigest()
            for root in roots for p in sorted(root.rglob("*")) if p.is_file()}


def error_line(result: subprocess.CompletedProcess[str]) -> str:
    """Check exit status 2 and a one-line ``error:`` message without traceback; return it."""
    detail = f"stdout:\n{result.stdout}\nstderr:\n{result.stderr}"
    assert result.returncode == 2, detail
    assert "Traceback" not in result.stderr, detail
    message = result.stderr.strip()
    assert len(message.splitlines()) == 1, detail
    assert message.startswith("error: "), detail
    return message


def names(message: str, path: Path) -> bool:
    """Whether ``message`` names ``path`` (as given or resolved)."""
    return str(path) in message or str(path.resolve()) in message


def load(path: Path) -> dict:
    """A scene file as a dictionary."""
    return yaml.safe_load(path.read_text())


def dump(doc: dict, path: Path) -> Path:
    """Write ``doc`` as YAML to ``path``; returns ``path``."""
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def baked(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(scene file, work directory) of a small Cornell box baked once for the module."""
    root = tmp_path_factory.mktemp("baked")
    shutil.copytree(SCENES / "cornell_box", root / "cornell_box")
    doc = load(SCENES / "cornell_box.yaml")
    doc["camera"]["width"] = doc["camera"]["height"] = SIZE
    doc["settings"] = {"gather.count": 1024}  # small d2i bake
    for spec in doc["objects"].values():  # absolute, so copies of the scene find the meshes
        spec["mesh"] = str((root / spec["mesh"]).resolve())
    scene = dump(doc, root / "cornell_box.yaml")
    workdir = root / "work"
    result = prt("run", scene, "--workdir", workdir, "--frames", root / "frames", "-q",
                 cwd=root)
    assert result.returncode == 0, result.stderr
    assert (workdir / "geometry.zarr").is_dir() and (workdir / "gbuffer.zarr").is_dir()
    return scene, workdir


@pytest.fixture
def case(baked: tuple[Path, Path], tmp_path: Path) -> tuple[Path, Path]:
    """(scene file, work directory): this test's copies of the baked scene (whose mesh paths
    are absolute, so the copy finds them) and of the baked artifacts."""
    scene, workdir = baked
    shutil.copy(scene, tmp_path / scene.name)
    shutil.copytree(workdir, tmp_path / "work")
    return tmp_path / scene.name, tmp_path / "work"


def run_scene(scene: Path, workdir: Path) -> subprocess.CompletedProcess[str]:
    """``prt run SCENE --workdir WORKDIR`` from the scene's folder."""
    return prt("run", scene, "--workdir", workdir, "--frames", scene.parent / "frames", "-q",
               cwd=scene.parent)


# --------------------------------------------------------------------------- scene files


def test_malformed_yaml(case: tuple[Path, Path]) -> None:
    """A scene file that is not valid YAML names the file and says 'malformed YAML'."""
    scene, workdir = case
    before = snapshot(workdir)
    text = scene.read_text().replace("fov: 39.3077", "fov: [39.3077")
    assert text != scene.read_text()
    bad = scene.with_name("malformed.yaml")
    bad.write_text(text)
    message = error_line(run_scene(bad, workdir))
    assert names(message, bad), message
    assert "malformed YAML" in message, message
    assert snapshot(workdir) == before


def test_unknown_key(case: tuple[Path, Path]) -> None:
    """An unknown camera key names the file, the key path and the key."""
    scene, workdir = case
    before = snapshot(workdir)
    doc = load(scene)
    doc["camera"]["zoom"] = 2
    bad = dump(doc, scene.with_name("unknown_key.yaml"))
    message = error_line(run_scene(bad, workdir))
    assert names(message, bad), message
    assert "unknown key" in message and "zoom" in message and "camera" in message, message
    assert snapshot(workdir) == before


@pytest.mark.parametrize(("name", "value", "expected"), [
    ("gather.count", "many", "is not an integer"), ("gather.count", "1e12", "is not an integer"),
    ("gather.count", 4096.0, "is not an integer"), ("brdf_basis.tolerance", "low", "a number"),
    ("sg.fit_match_integral", 1, "true or false"), ("sg.fit_grid", 55, "a list"),
    # issue 40 items 4 and 6: sizes that asked for 7.8 TiB, and an error without FILE
    ("gather.count", 10 ** 12, "1000000000000 is outside 1..1048576"),
    ("sg.fit_max_lobes", 0, "0 is outside 1..3"), ("gather.area_samples", -5, "outside"),
    ("triple.frame_grid", [64, 0, 32], "0 is outside 2..512"),
    ("sg.fit_spatial_weight", -0.5, "-0.5 is outside ≥ 0"),
    ("brdf_basis.tolerance", float("nan"), "nan is outside 0..1")])
def test_a_setting_of_the_wrong_kind(case: tuple[Path, Path], name: str, value: object,
                                     expected: str) -> None:
    """A stage parameter given as text, or a float where the default is an integer, or a
    number outside the parameter's limits (stages.yaml ``limits``; else finite and not
    negative) is one error line naming the file, the setting and what it should be (a
    traceback, or a 7.8 TiB allocation for gather.count: 10^12, before)."""
    scene, workdir = case
    before = snapshot(workdir)
    doc = load(scene)
    doc["settings"] = {**doc.get("settings", {}), name: value}
    bad = dump(doc, scene.with_name("bad_setting.yaml"))
    message = error_line(run_scene(bad, workdir))
    assert names(message, bad) and f"settings.{name}: " in message and expected in message
    assert snapshot(workdir) == before


def test_missing_mesh_file(case: tuple[Path, Path]) -> None:
    """A mesh path that does not exist names the scene, the mesh path and 'not found'."""
    scene, workdir = case
    before = snapshot(workdir)
    doc = load(scene)
    doc["objects"]["floor"]["mesh"] = "cornell_box/cbox_missing.obj"
    bad = dump(doc, scene.with_name("missing_mesh.yaml"))
    message = error_line(run_scene(bad, workdir))
    assert names(message, bad), message
    assert names(message, scene.parent / "cornell_box" / "cbox_missing.obj"), message
    assert "not found" in message, message
    assert snapshot(workdir) == before


def test_mesh_with_nan_vertices(case: tuple[Path, Path]) -> None:
    """A mesh whose faces use a NaN vertex names the mesh file and says 'non-finite'."""
    scene, workdir = case
    before = snapshot(workdir)
    mesh = scene.with_name("nan_box.obj")
    mesh.write_text("v 0 0 0\nv nan 0 0\nv 0 100 0\nv 100 100 0\nf 1 2 3\nf 1 3 4\n")
    doc = load(scene)
    doc["objects"]["smallbox"]["mesh"] = mesh.name
    bad = dump(doc, scene.with_name("nan_mesh.yaml"))
    message = error_line(run_scene(bad, workdir))
    assert names(message, mesh), message
    assert "non-finite" in message, message
    assert snapshot(workdir) == before


def test_unknown_material_model(case: tuple[Path, Path]) -> None:
    """An unknown material model names the file, the key, 'unknown value' and the model."""
    scene, workdir = case
    before = snapshot(workdir)
    doc = load(scene)
    doc["materials"]["glossy_floor"]["model"] = "disney_principled"
    bad = dump(doc, scene.with_name("unknown_model.yaml"))
    message = error_line(run_scene(bad, workdir))
    assert names(message, bad), message
    assert "unknown value" in message and "disney_principled" in message, message
    assert "materials.glossy_floor.model" in message, message
    assert snapshot(workdir) == before


# --------------------------------------------------------------------------- image size


@pytest.mark.parametrize("size", ["0x64", "-4x8"])
def test_render_size_not_positive(case: tuple[Path, Path], size: str) -> None:
    """``prt render --size`` with a zero or negative side names the option and value."""
    scene, workdir = case
    before = snapshot(workdir)
    out = scene.parent / "frame.exr"
    result = prt("render", scene, "--workdir", workdir, "--out", out, "--size", size, "-q",
                 cwd=scene.parent)
    message = error_line(result)
    assert "--size" in message and size in message, message
    assert "positive" in message, message
    assert not out.exists() and not out.with_suffix(".png").exists()
    assert snapshot(workdir) == before


@pytest.mark.parametrize(("key", "value"), [("width", 0), ("height", -4)])
def test_scene_camera_size_not_positive(case: tuple[Path, Path], key: str, value: int) -> None:
    """A camera width/height below 1 in the scene names the file, key and value."""
    scene, workdir = case
    before = snapshot(workdir)
    doc = load(scene)
    doc["camera"][key] = value
    bad = dump(doc, scene.with_name(f"camera_{key}.yaml"))
    out = scene.parent / "frame.exr"
    result = prt("render", bad, "--workdir", workdir, "--out", out, "-q", cwd=scene.parent)
    message = error_line(result)
    assert names(message, bad), message
    assert f"camera.{key}" in message and str(value) in message, message
    assert ">= 1" in message or "positive" in message, message
    assert not out.exists()
    assert snapshot(workdir) == before


# --------------------------------------------------------------------------- work directory


def test_unwritable_workdir(case: tuple[Path, Path]) -> None:
    """A work directory below a regular file names the folder and says 'not writable'."""
    scene, workdir = case
    before = snapshot(workdir)
    afile = scene.parent / "afile"
    afile.write_text("not a folder\n")
    target = afile / "sub"
    message = error_line(run_scene(scene, target))
    assert names(message, target), message
    assert "not writable" in message, message
    assert afile.read_text() == "not a folder\n"
    assert snapshot(workdir) == before


# --------------------------------------------------------------------------- artifacts


def test_artifact_other_schema_version(case: tuple[Path, Path]) -> None:
    """An artifact of schema version 99 names the artifact and the version; nothing lost."""
    scene, workdir = case
    artifact = workdir / "gbuffer.zarr"
    meta = artifact / "zarr.json"
    doc = json.loads(meta.read_text())
    assert doc["attributes"]["prt"]["schema_version"] != 99
    doc["attributes"]["prt"]["schema_version"] = 99
    meta.write_text(json.dumps(doc, indent=2))
    corrupted = str(meta.relative_to(workdir))
    before = snapshot(workdir)
    out = scene.parent / "frame.exr"
    result = prt("render", scene, "--workdir", workdir, "--out", out, "-q", cwd=scene.parent)
    message = error_line(result)
    assert names(message, artifact), message
    assert "version" in message and "99" in message, message
    after = snapshot(workdir)
    assert meta.is_file()
    before.pop(corrupted)
    after.pop(corrupted, None)
    assert after == before


def test_truncated_chunk(case: tuple[Path, Path]) -> None:
    """A truncated zarr chunk names the chunk file and says 'corrupt or truncated'."""
    scene, workdir = case
    chunk = workdir / "gbuffer.zarr" / "position" / "c" / "0" / "0" / "0"
    assert chunk.is_file() and chunk.stat().st_size > 8
    chunk.write_bytes(chunk.read_bytes()[:5])
    corrupted = str(chunk.relative_to(workdir))
    before = snapshot(workdir)
    out = scene.parent / "frame.exr"
    result = prt("render", scene, "--workdir", workdir, "--out", out, "-q", cwd=scene.parent)
    message = error_line(result)
    assert names(message, chunk), message
    assert "corrupt or truncated" in message, message
    after = snapshot(workdir)
    assert chunk.is_file()
    before.pop(corrupted)
    after.pop(corrupted, None)
    assert after == before


@pytest.mark.parametrize("address", ["bogus", "tcp://host", "host:99999", "local:0"])
def test_a_malformed_scheduler_address_touches_nothing(case: tuple[Path, Path],
                                                       address: str) -> None:
    """Issue 40 item 4: ``--scheduler bogus`` was a traceback (dask's "missing port
    number", exit 1) that left the ``--force``d stage partial. Now the address is read
    before anything (and a remote scheduler reached before any stage is touched)."""
    scene, workdir = case
    before = snapshot(workdir)
    message = error_line(prt("run", scene, "--workdir", workdir, "--force", "gbuffer",
                             "--scheduler", address, "-q", cwd=scene.parent))
    assert message.startswith("error: --scheduler: ") and repr(address) in message
    assert snapshot(workdir) == before


# ------------------------------------------------- issue 40 item 6: refused with the right words


@pytest.mark.parametrize(("option", "expected"), [
    ("max_bounces=-1", "max_bounces='-1': expected a number >= 0"),
    ("bounce_tolerance=-5", "bounce_tolerance='-5': expected a number >= 0"),
    ("shadows=gpu", "shadows='gpu': expected one of device, embree, auto")])
def test_a_run_time_option_out_of_range(case: tuple[Path, Path], option: str,
                                        expected: str) -> None:
    """``--option max_bounces=-1`` rendered (as 0); now refused before any bake."""
    scene, workdir = case
    before = snapshot(workdir)
    message = error_line(prt("render", scene, "--workdir", workdir, "--option", option,
                             "--out", scene.parent / "x.exr", "-q", cwd=scene.parent))
    assert message == f"error: --option: {expected}"
    assert snapshot(workdir) == before and not (scene.parent / "x.exr").exists()


def test_a_scene_file_not_in_utf8(case: tuple[Path, Path]) -> None:
    """A Latin-1 scene file said "not a text file"; now where and what to do."""
    scene, workdir = case
    bad = scene.with_name("latin1.yaml")
    bad.write_bytes(scene.read_bytes().replace(b"name: ", b"name: caf\xe9", 1))
    message = error_line(run_scene(bad, workdir))
    assert message.startswith(f"error: {bad}: not UTF-8 text (byte 0xe9 at line ")
    assert message.endswith("save it as UTF-8")


def test_an_output_path_under_a_file(case: tuple[Path, Path]) -> None:
    """``--out FILE/x.exr`` said "(File exists)"; now which path is in the way."""
    scene, workdir = case
    blocking = scene.parent / "afile"
    blocking.write_text("")
    message = error_line(prt("render", scene, "--workdir", workdir, "--out",
                             blocking / "x.exr", "-q", cwd=scene.parent))
    assert message == (f"error: {blocking / 'x.exr'}: cannot write an image here: "
                       f"{blocking} is a file, not a folder")


def test_a_png_environment_map(tmp_path: Path) -> None:
    """A PNG map said "cannot read EXR"; a PNG holds display values, not radiance."""
    from PIL import Image

    png = tmp_path / "sky.png"
    Image.new("RGB", (16, 8), (120, 160, 220)).save(png)
    doc = load(SCENES / "bunny_grace.yaml")
    doc["lights"] = [{"type": "environment", "file": str(png)}]
    scene = dump(doc, tmp_path / "png_env.yaml")
    message = error_line(prt("run", scene, "--workdir", tmp_path / "w", "-q", cwd=tmp_path))
    assert message.startswith(f"error: {png}: an environment map must be an OpenEXR (.exr) "
                              "or Radiance (.hdr) file")
    assert not (tmp_path / "w").exists()

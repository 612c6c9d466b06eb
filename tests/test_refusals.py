"""Issue 15, item 7 and the rest of item 3: inputs that used to end in a traceback (or
silently in the wrong result) give one line ``error: FILE: PROBLEM``, exit 2, before any
work, and touch no artifact; a read-only, fully baked work directory renders.

A module fixture bakes a tiny 8x8 scene (method direct) once; tests that need baked
artifacts copy its work directory and compare every file's content before and after.
Permission tests drop root's permission-bypassing capabilities with setpriv (util-linux)
when run as root, and are skipped where that is not possible.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import PROJECT, small_scene_dict, write_scene

from pipeline.errors import PrtError

IS_ROOT = os.geteuid() == 0
# Root ignores file permissions through these capabilities; without them it does not.
DROP_ROOT_BYPASS = ["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner",
                    "--"]


def _can_drop_root_bypass() -> bool:
    if shutil.which("setpriv") is None:
        return False
    return subprocess.run([*DROP_ROOT_BYPASS, "true"], capture_output=True).returncode == 0


def prt(*args: str | Path, cwd: Path, unprivileged: bool = False
        ) -> subprocess.CompletedProcess[str]:
    """``python -m pipeline ARGS`` in ``cwd``; ``unprivileged``: as root, without the
    capabilities that bypass file permissions (skips the test where that is impossible)."""
    prefix: list[str] = []
    if unprivileged and IS_ROOT:
        if not _can_drop_root_bypass():
            pytest.skip("running as root, which ignores file permissions, and setpriv "
                        "cannot drop that")
        prefix = DROP_ROOT_BYPASS
    return subprocess.run([*prefix, sys.executable, "-m", "pipeline", *map(str, args)],
                          cwd=cwd, capture_output=True, text=True, timeout=300)


def error_line(result: subprocess.CompletedProcess[str]) -> str:
    """Assert exit status 2 and one ``error:`` line without traceback; return it."""
    detail = f"stdout:\n{result.stdout}\nstderr:\n{result.stderr}"
    assert result.returncode == 2, detail
    message = result.stderr.strip()
    assert "Traceback" not in message and len(message.splitlines()) == 1, detail
    assert message.startswith("error: "), detail
    return message


def listing(folder: Path) -> dict[str, str]:
    """The SHA-256 of every file under ``folder`` (a folder: ``"folder"``), less the
    scratch folder ``.tmp`` of writes in progress."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            if p.is_file() else "folder" for p in sorted(folder.rglob("*"))
            if p.relative_to(folder).parts[0] != ".tmp"}


@pytest.fixture(scope="module")
def baked(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    """(scene dictionary, work directory) of the tiny scene baked once for the module."""
    root = tmp_path_factory.mktemp("baked")
    doc = small_scene_dict(size=8)
    scene = write_scene(root, doc)
    result = prt("run", scene, "--workdir", root / "work", "--frames", root / "frames",
                 "-q", cwd=root)
    assert result.returncode == 0, result.stderr
    return doc, root / "work"


@pytest.fixture
def case(baked: tuple[dict, Path], tmp_path: Path) -> tuple[dict, Path]:
    """This test's copy of the scene dictionary and of the baked work directory."""
    doc, workdir = baked
    shutil.copytree(workdir, tmp_path / "work")
    return copy.deepcopy(doc), tmp_path / "work"


# --------------------------------------------------------------------------- scenes


def test_camera_up_parallel_to_the_view(case, tmp_path):
    """An `up` along the view direction is refused when the scene is read (it used to
    pass validation and fail in the renderer with a ValueError)."""
    doc, workdir = case
    doc["camera"].update(position=[0, 4, 0], look_at=[0, 0, 0], up=[0, 2, 0])
    scene = write_scene(tmp_path, doc)
    before = listing(workdir)
    message = error_line(prt("render", scene, "--workdir", workdir, "--out",
                             tmp_path / "f.exr", "-q", cwd=tmp_path))
    assert message.startswith(f"error: {scene}: camera.up: [0.0, 2.0, 0.0] is parallel "
                              "to the view direction"), message
    assert listing(workdir) == before and not (tmp_path / "f.exr").exists()


def test_absurd_image_sizes(case, tmp_path):
    """`width: 10000000` and `--size 20000x20` are refused with the documented limit."""
    doc, workdir = case
    doc["camera"]["width"] = 10_000_000
    scene = write_scene(tmp_path, doc)
    before = listing(workdir)
    message = error_line(prt("render", scene, "--workdir", workdir, "--out",
                             tmp_path / "f.exr", "-q", cwd=tmp_path))
    assert message == (f"error: {scene}: camera.width: expected an integer <= 16384 (the "
                       "largest image side prt renders), found 10000000")
    good = write_scene(tmp_path, small_scene_dict(size=8), "good.yaml")
    message = error_line(prt("render", good, "--size", "20000x20", "--workdir", workdir,
                             "--out", tmp_path / "f.exr", "-q", cwd=tmp_path))
    assert message == "error: --size: '20000x20': at most 16384 pixels per side"
    assert listing(workdir) == before


def test_duplicate_key_in_a_scene_file(case, tmp_path):
    """A key given twice in one mapping is refused, naming the key and both lines."""
    _, workdir = case
    scene = tmp_path / "dup.yaml"
    text = write_scene(tmp_path, small_scene_dict(size=8)).read_text()
    scene.write_text(text.replace("name: tiny\n", "name: tiny\nname: other\n"))
    before = listing(workdir)
    message = error_line(prt("run", scene, "--workdir", workdir, "-q", cwd=tmp_path))
    assert message == f"error: {scene}: line 3: duplicate key 'name' (first at line 2)"
    assert listing(workdir) == before


def test_duplicate_key_in_a_stage_file(tmp_path):
    """stages.yaml with a stage declared twice (the second used to replace the first)."""
    text = (PROJECT / "stages.yaml").read_text()
    stages = tmp_path / "stages.yaml"
    block = text[text.index("  gbuffer:\n"):]  # the file's last stage
    assert "impl: gbuffer" in block and block.endswith("\n")
    stages.write_text(text.replace(block, block + block, 1))
    scene = write_scene(tmp_path, small_scene_dict(size=8))
    message = error_line(prt("run", scene, "--stages", stages, "--workdir", tmp_path / "w",
                             "-q", cwd=tmp_path))
    assert message.startswith(f"error: {stages}: line ") and \
        "duplicate key 'gbuffer' (first at line" in message, message
    assert not (tmp_path / "w").exists()


def test_a_material_that_gains_energy(case, tmp_path):
    """albedo + specular x the model's albedo bound > 1 is refused, naming the material
    and the sum; a run-time `--set` edit is checked the same way."""
    doc, workdir = case
    doc["materials"]["shiny"]["specular"] = 0.3  # 0.6 + 0.3 x 3.947 (γ up to 300)
    scene = write_scene(tmp_path, doc)
    before = listing(workdir)
    message = error_line(prt("render", scene, "--workdir", workdir, "--out",
                             tmp_path / "f.exr", "-q", cwd=tmp_path))
    assert message.startswith(
        f"error: {scene}: materials.shiny: albedo + specular x 3.95 = 0.6 + 0.3 x 3.95 = "
        "1.78 > 1 in the blue channel: the material reflects more light than it "
        "receives"), message
    good = write_scene(tmp_path, small_scene_dict(size=8), "good.yaml")
    message = error_line(prt("render", good, "--set", "shiny.specular=0.5", "--workdir",
                             workdir, "--out", tmp_path / "f.exr", "-q", cwd=tmp_path))
    assert "materials.shiny: albedo + specular x 3.95" in message, message
    assert listing(workdir) == before and not (tmp_path / "f.exr").exists()


def test_the_blinn_phong_bound_is_its_largest_directional_albedo():
    """The closed form used by the energy check equals the numerically integrated
    directional albedo at normal incidence, which is the largest over view angles (to
    2e-3 relative: the midpoint rule on 1024 x 256 half vectors)."""
    from pipeline.math import brdf

    for gamma in (1.0, 30.0, 300.0):
        p = brdf.BrdfParams("blinn_phong", (0, 0, 0), (1, 1, 1), gamma)
        albedo = []
        for theta in np.radians([0.0, 30.0, 60.0, 85.0]):
            wo = np.array([np.sin(theta), 0.0, np.cos(theta)])
            albedo.append(brdf.directional_albedo(
                lambda wi, wo=wo, p=p: brdf.glossy(wi, np.broadcast_to(wo, wi.shape), p),
                wo, 1024, 256))
        bound = brdf.specular_albedo_bound("blinn_phong", gamma)
        assert abs(albedo[0] - bound) <= 2e-3 * bound, (gamma, albedo, bound)
        assert max(albedo) <= bound * (1 + 2e-3), (gamma, albedo, bound)
    assert brdf.specular_albedo_bound("ward_duer", 0.5) is None


# --------------------------------------------------------------------------- meshes

OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n"


@pytest.mark.parametrize(("data", "problem"), [
    (b"\x00\x01garbage\xff\xfe", "not a text OBJ file (it holds binary data)"),
    ("caf\xe9 v 1 2 3\n".encode("latin-1"), "not a text OBJ file (byte 3 is not UTF-8)"),
    (OBJ.encode() + b"v 1 2", "line 7: 'v 1 2': expected 3 to 6 numbers (is the file cut "
     "short?)"),
    (OBJ.encode() + b"f 1 2", "line 7: 'f 1 2': a face needs at least 3 corners (is the "
     "file cut short?)"),
    (OBJ.replace("f 2 4 3", "f 2 4 9").encode(), "line 6: 'f 2 4 9': corner '9' names v 9, "
     "but 4 are defined above it"),
    (OBJ.replace("f 2 4 3", "f 2 4 0").encode(), "line 6: 'f 2 4 0': corner '0' names v 0, "
     "but 4 are defined above it"),
    (OBJ.replace("v 1 1 0", "v 1 x 0").encode(), "line 4: 'v 1 x 0': expected numbers"),
])
def test_malformed_obj_files(tmp_path, data, problem):
    """Each malformed OBJ is one PrtError naming the file and the line (trimesh crashed on
    some, with ModuleNotFoundError or a NumPy broadcast error, and silently read
    another mesh from others)."""
    from pipeline.scene.meshio import read_mesh

    path = tmp_path / "m.obj"
    path.write_bytes(data)
    with pytest.raises(PrtError) as error:
        read_mesh(path)
    assert error.value.one_line() == f"{path}: {problem}"


def test_well_formed_obj_reads_the_same(tmp_path):
    """The checked reader gives trimesh's mesh for a well-formed OBJ, with negative,
    v/vt and v//vn corners."""
    from pipeline.scene.meshio import read_mesh

    path = tmp_path / "m.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 1\nvn 0 0 1\n"
                    "f 1/1 2/2 3/1\nf 2//1 4//1 -2//1\n")
    mesh = read_mesh(path)
    assert mesh.faces.shape == (2, 3) and np.isfinite(mesh.vertices).all()


def test_weld_joins_per_face_normal_splits_keeps_uv_seams(tmp_path):
    """Trimesh splits an OBJ vertex per (v, vn) pair, and read_mesh keeps the split (a
    file's hard edges); ``weld`` (the scene's ``smooth: true``) joins bit-identical
    positions back, in order of first appearance, but keeps vertices that differ in uv
    (a texture seam) apart. The shared bunny_6.6kf.obj is 19,794 faceted vertices for
    3,301 positions."""
    from pipeline.scene.meshio import read_mesh, weld

    quad = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
    path = tmp_path / "flat.obj"
    path.write_text(quad + "vn 0 0 1\nvn 0 0.1 1\nf 1//1 2//1 3//1\nf 2//2 4//2 3//2\n")
    assert len(read_mesh(path).vertices) == 6
    mesh = weld(read_mesh(path))
    assert len(mesh.vertices) == 4
    assert np.array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert np.array_equal(mesh.faces, [[0, 1, 2], [1, 3, 2]])

    seam = tmp_path / "seam.obj"
    seam.write_text(quad + "vt 0 0\nvt 1 0\nvt 0 1\nvt 0.5 0.5\nvt 1 1\n"
                    "f 1/1 2/2 3/3\nf 2/4 4/5 3/3\n")
    mesh = weld(read_mesh(seam))
    # vertex 2 appears with uv (1, 0) and (0.5, 0.5): two vertices; vertex 3 shares its uv
    assert len(mesh.vertices) == 5
    assert mesh.faces[0, 2] == mesh.faces[1, 2]
    assert mesh.faces[0, 1] != mesh.faces[1, 0]


@pytest.mark.parametrize("damage", ["garbage", "truncated"])
def test_a_damaged_mesh_in_a_scene(case, tmp_path, damage):
    """`prt run` with a garbage or a truncated OBJ: one line naming the mesh file; the
    baked artifacts are untouched."""
    doc, workdir = case
    good = PROJECT / "scenes" / "cornell_box" / "cbox_smallbox.obj"
    mesh = tmp_path / "box.obj"
    mesh.write_bytes(b"\x89PNG\r\n\x1a\n\x00garbage" if damage == "garbage"
                     else good.read_bytes()[:1330])  # within a face line
    doc["objects"]["box"] = {"mesh": mesh.name, "material": "red",
                             "transform": {"scale": 0.003}}
    scene = write_scene(tmp_path, doc)
    before = listing(workdir)
    message = error_line(prt("run", scene, "--workdir", workdir, "--frames",
                             tmp_path / "frames", "-q", cwd=tmp_path))
    assert message.startswith(f"error: {mesh}: "), message
    assert ("binary data" if damage == "garbage" else "is the file cut short?") in message
    assert listing(workdir) == before
    assert not (tmp_path / "frames").exists()


# --------------------------------------------------------------------------- files


def test_render_out_into_a_read_only_folder(tmp_path):
    """`prt render --out` into a folder that cannot be written is refused before the bake
    (it used to bake, then fail with OpenEXR's RuntimeError)."""
    scene = write_scene(tmp_path, small_scene_dict(size=8))
    folder = tmp_path / "readonly"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        message = error_line(prt("render", scene, "--out", folder / "f.exr", "--workdir",
                                 tmp_path / "w", "-q", cwd=tmp_path, unprivileged=True))
    finally:
        folder.chmod(0o755)
    assert message == f"error: {folder / 'f.exr'}: cannot write an image here (Permission " \
                      "denied)"
    assert not (tmp_path / "w").exists() and not any(folder.iterdir())


def test_clean_of_a_missing_work_directory(tmp_path):
    """`prt clean --workdir does_not_exist` says there is nothing to remove (it said
    "Removed") and creates nothing."""
    scene = write_scene(tmp_path, small_scene_dict(size=8))
    message = error_line(prt("clean", scene, "--workdir", "does_not_exist", cwd=tmp_path))
    assert message == (f"error: {tmp_path / 'does_not_exist'}: no such work directory; "
                       "nothing to remove")
    assert not (tmp_path / "does_not_exist").exists()


def test_a_read_only_baked_work_directory_renders(case, tmp_path):
    """With every stage fresh, rendering needs no write into the work directory (no
    lock, no marker): a read-only copy renders, and nothing in it changes. A stale stage
    (another image size: its own view, not built yet) is named instead of a permission
    traceback."""
    doc, workdir = case
    scene = write_scene(tmp_path, doc)
    before = listing(workdir)
    subprocess.run(["chmod", "-R", "a-w", str(workdir)], check=True)
    try:
        result = prt("render", scene, "--workdir", workdir, "--out", tmp_path / "f.exr",
                     "-q", cwd=tmp_path, unprivileged=True)
        assert result.returncode == 0, result.stderr
        assert (tmp_path / "f.exr").is_file()
        message = error_line(prt("render", scene, "--size", "6x6", "--workdir", workdir,
                                 "--out", tmp_path / "g.exr", "-q", cwd=tmp_path,
                                 unprivileged=True))
    finally:
        subprocess.run(["chmod", "-R", "u+w", str(workdir)], check=True)
    assert message == (f"error: {workdir}: work directory is not writable and stage gbuffer "
                       "is missing (not built yet); make it writable or give "
                       "another --workdir")
    assert listing(workdir) == before


# --------------------------------------------------------------------------- evaluate


@pytest.mark.parametrize(("sweep", "problem"), [
    ("size=abc", "size=abc: expected a width or WIDTHxHEIGHT, positive integers up to "
     "16384"),
    ("render.max_bounces=1,2", "method direct has no budget 'render.max_bounces' (its "
     "budgets: size, gbuffer.tile, geometry.vertex_chunk)"),
    ("gbuffer.tile=abc", "gbuffer.tile=abc: expected a finite number (the scene's value "
     "is 64)"),
])
def test_evaluate_sweep_refused_before_any_work(tmp_path, sweep, problem):
    """A sweep value of the wrong kind (ValueError before) or a budget the method does
    not have (TypeError before) names --sweep and, for a name, the method's budgets."""
    scene = write_scene(tmp_path, small_scene_dict(size=8))
    message = error_line(prt("evaluate", scene, "--method", "direct", "--sweep", sweep,
                             "--out", tmp_path / "ev", "--workdir", tmp_path / "w", "-q",
                             cwd=tmp_path))
    assert message == f"error: --sweep: {problem}"
    assert not (tmp_path / "ev").exists() and not (tmp_path / "w").exists()


# --------------------------------------------------------------- what methods render


def test_a_material_or_feature_a_method_does_not_render(tmp_path):
    """A method declares its material models and scene features; a scene using another
    is refused before any bake, naming the material (or feature) and the methods that
    render it."""
    import dataclasses

    from pipeline.registry import check_method_scene, get_method
    from pipeline.scene.file import load_scene

    diffuse_only = dataclasses.replace(get_method("direct"), name="diffuse_only",
                                       materials=("lambert",), features=())
    scene = load_scene(write_scene(tmp_path, small_scene_dict(size=8)))
    with pytest.raises(PrtError) as error:
        check_method_scene(diffuse_only, scene)
    assert error.value.problem == ("materials.shiny: method diffuse_only does not render "
                                   "blinn_phong materials (methods that do: d2i, direct, sg, "
                                   "triple)")
    doc = small_scene_dict(size=8)
    doc["materials"]["shiny"] = {"model": "lambert"}
    doc["lights"][1]["object"] = "box"
    scene = load_scene(write_scene(tmp_path, doc))
    with pytest.raises(PrtError) as error:
        check_method_scene(diffuse_only, scene)
    assert error.value.problem.startswith("lights[1].object: method diffuse_only does not "
                                          "render the emitting object of a quad light")
    assert check_method_scene(get_method("direct"), scene) == []


def test_notes_come_before_the_bake_and_in_json(tmp_path):
    """A note (here: a ward_duer material, whose energy cannot be checked) is printed
    before the bake's progress, and is in `--json` output."""
    doc = small_scene_dict(size=8)
    doc["materials"]["shiny"] = {"model": "ward_duer", "albedo": 0.2, "specular": 0.1,
                                 "gamma": 0.3}
    scene = write_scene(tmp_path, doc)
    note = ("note: materials.shiny: ward_duer has no bounded albedo (it grows towards "
            "grazing angles), so whether it conserves energy is not checked")
    result = prt("run", scene, "--workdir", tmp_path / "w", "--frames", tmp_path / "fr",
                 cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stderr.startswith(note + "\n"), result.stderr[:300]
    assert "geometry" in result.stderr  # the bake's progress follows the note
    result = prt("render", scene, "--workdir", tmp_path / "w", "--out", tmp_path / "f.exr",
                 "--json", "-q", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["notes"] == [note.removeprefix("note: ")]

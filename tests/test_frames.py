"""The frames `prt run` owns and the bakes of other image sizes (issue 15, items 5, 6
and 8): a `--size` preview keeps its camera-dependent artifacts apart and never replaces
the file's bake; every frame and sequence frame missing or changed on disk is rendered
again; `prt status` shows their state; a light sequence names its light and path, skips
a scene with no light to move, and draws a moved quad light where it is."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from helpers import small_scene_dict, write_scene

from pipeline import job
from pipeline.engine.graph import dependent_on, with_upstream
from pipeline.engine.store import Workdir, read_record
from pipeline.images import read_exr
from pipeline.render.emitters import EmitterOverlay, moved_quads
from pipeline.scene.edits import with_light_offset
from pipeline.scene.file import load_scene
from pipeline.scene.model import Camera


def prt(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def _d2i_doc(size: int) -> dict:
    doc = small_scene_dict(size=size)
    doc["settings"] = {"gather.count": 256}  # a small d2i bake
    doc["methods"] = ["d2i"]
    return doc


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """A tiny d2i scene (16²) through `prt run`: (scene, workdir, frames)."""
    tmp = tmp_path_factory.mktemp("frames")
    scene = write_scene(tmp, _d2i_doc(16))
    first = prt("run", scene, "--workdir", tmp / "w", "--frames", tmp / "f", "-q")
    assert first.returncode == 0, first.stderr
    return scene, tmp / "w", tmp / "f"


def _status(scene, workdir, frames, *extra) -> dict:
    out = prt("status", scene, "--workdir", workdir, "--frames", frames, "--json", *extra)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def _records(workdir) -> dict[str, tuple[str, int]]:
    """Key and zarr.json mtime of every artifact at the work directory's top level."""
    return {p.name: (read_record(p)["key"], (p / "zarr.json").stat().st_mtime_ns)
            for p in sorted(workdir.glob("*.zarr"))}


def test_camera_dependent_stages():
    """The stages kept per image size are those reading the camera and their
    downstream; geometry and the BRDF bases are shared. triple.atlas sizes textures by
    the objects' size on screen, so it and the visibility read from it are kept per
    size too."""
    assert dependent_on(job.stages(), "camera") == {
        "gbuffer", "d2i.gather", "d2i.transfer", "d2i.transfer_t", "d2i.bounce",
        "d2i.truncate", "d2i.truncate_t", "d2i.truncate_ms", "triple.atlas",
        "triple.visibility"}


def test_workdir_places_a_resized_scenes_camera_artifacts_apart(tmp_path):
    scene = load_scene(write_scene(tmp_path, small_scene_dict(size=16)))
    assert scene.view is None and job.workdir_for(scene, tmp_path).views == ()
    small = scene.with_image_size(8, 4)
    wd = job.workdir_for(small, tmp_path / "w")
    assert small.view == "8x4"
    assert wd.artifact("gbuffer") == tmp_path / "w" / "views" / "8x4" / "gbuffer.zarr"
    assert wd.artifact("geometry") == tmp_path / "w" / "geometry.zarr"
    assert wd.marker("gbuffer", "0_0").parent.parent.parent == wd.root / "views" / "8x4"
    # back at the file's size: the file's own bake
    assert small.with_image_size(16, 16).view is None
    assert Workdir(tmp_path).artifact("gbuffer") == tmp_path / "gbuffer.zarr"


def test_size_preview_keeps_the_files_bake(baked, tmp_path):
    """`prt render --size 8x8` bakes its own camera-dependent artifacts under
    views/8x8 and reuses geometry and the BRDF bases; the 16² bake is untouched: `prt
    status` says fresh (blaming nothing) and `prt run` bakes and renders nothing."""
    scene, workdir, frames = baked
    before = _records(workdir)
    out = prt("render", scene, "--workdir", workdir, "--size", "8x8", "--out",
              tmp_path / "p.exr", "-q")
    assert out.returncode == 0, out.stderr
    assert read_exr(tmp_path / "p.exr").shape == (8, 8, 3)
    view = workdir / "views" / "8x8"
    graph = job.stages()
    baked_here = with_upstream(graph, sorted(job.baked_stages(load_scene(scene))))
    assert sorted(p.name for p in view.glob("*.zarr")) == sorted(
        f"{s}.zarr" for s in dependent_on(graph, "camera") & baked_here)
    assert _records(workdir) == before  # same keys, not rewritten
    status = _status(scene, workdir, frames)
    assert {s["state"] for s in status["stages"]} == {"fresh"}
    assert {f["state"] for f in status["frames"]} == {"present"}
    again = prt("run", scene, "--workdir", workdir, "--frames", frames, "-q")
    assert "nothing to bake" in again.stdout and "Frame up to date" in again.stdout
    assert "Sequence light: up to date" in again.stdout


def test_run_size(baked):
    """`prt run --size 8x8` writes its frame and sequences beside the file's, named by
    size, at that size; the file's frame stays present."""
    scene, workdir, frames = baked
    out = prt("run", scene, "--workdir", workdir, "--frames", frames, "--size", "8x8", "-q")
    assert out.returncode == 0, out.stderr
    assert read_exr(frames / "tiny_d2i_8x8.exr").shape == (8, 8, 3)
    assert read_exr(frames / "tiny_d2i_8x8_light_0007.exr").shape == (8, 8, 3)
    assert {f["state"] for f in _status(scene, workdir, frames)["frames"]} == {"present"}
    small = _status(scene, workdir, frames, "--size", "8x8")
    assert [f["path"] for f in small["frames"]][0] == str(frames / "tiny_d2i_8x8.exr")
    assert {f["state"] for f in small["frames"]} == {"present"}
    bad = prt("run", scene, "--workdir", workdir, "--size", "8y8")
    assert bad.returncode == 2 and "error: --size" in bad.stderr


def test_run_restores_deleted_and_garbage_sequence_frames(baked):
    """A deleted sequence frame and a truncated one are reported by `prt status`
    (missing, stale) and rendered again by `prt run`, which no longer says "up to
    date"; the main frame deleted is rendered again too."""
    scene, workdir, frames = baked
    light3 = frames / "tiny_d2i_light_0003.exr"
    gamma2 = frames / "tiny_d2i_gamma_0002.exr"
    good = read_exr(gamma2)
    light3.unlink()
    gamma2.write_bytes(gamma2.read_bytes()[:100])
    states = {f["name"]: (f["state"], f["reason"])
              for f in _status(scene, workdir, frames)["frames"]}
    assert states["frame"] == ("present", "")
    assert states["sequence light:8"][0] == "missing"
    assert "tiny_d2i_light_0003.exr" in states["sequence light:8"][1]
    assert states["sequence gamma:8"][0] == "stale"
    assert "tiny_d2i_gamma_0002.exr" in states["sequence gamma:8"][1]
    out = prt("run", scene, "--workdir", workdir, "--frames", frames, "-q")
    assert out.returncode == 0, out.stderr
    assert "Frame up to date" in out.stdout
    assert "Sequence light: 8 frames" in out.stdout and "Sequence gamma: 8 frames" in out.stdout
    assert light3.is_file()
    np.testing.assert_array_equal(read_exr(gamma2), good)  # the same frame, whole again
    (frames / "tiny_d2i.png").unlink()
    assert "Frame rendered" in prt("run", scene, "--workdir", workdir, "--frames",
                                   frames, "-q").stdout
    assert {f["state"] for f in _status(scene, workdir, frames)["frames"]} == {"present"}


def test_exposure_scales_the_preview_only(baked, tmp_path):
    """--exposure 2 makes the PNG brighter, the EXR is the same linear image; a changed
    exposure re-renders the previews of `prt run`; a non-finite one is refused."""
    scene, workdir, frames = baked
    from PIL import Image

    for ev in ("0", "2"):
        out = prt("render", scene, "--workdir", workdir, "--out", tmp_path / f"e{ev}.exr",
                  "--exposure", ev, "-q")
        assert out.returncode == 0, out.stderr
    np.testing.assert_array_equal(read_exr(tmp_path / "e0.exr"), read_exr(tmp_path / "e2.exr"))
    dark, bright = (np.asarray(Image.open(tmp_path / f"e{ev}.png"), float) for ev in "02")
    assert bright.mean() > dark.mean() + 10 and (bright >= dark).all()
    out = prt("run", scene, "--workdir", workdir, "--frames", frames, "--exposure", "1",
              "-q")
    assert "Frame rendered" in out.stdout and "Sequence gamma: 8 frames" in out.stdout
    bad = prt("render", scene, "--workdir", workdir, "--out", tmp_path / "x.exr",
              "--exposure", "inf")
    assert bad.returncode == 2 and "error: --exposure" in bad.stderr


def test_light_sequence_names_its_light_and_path(baked, tmp_path):
    """`--frames light:1:2` moves lights[1] (the quad) and prints its circle; a light
    that is not there or cannot move is a one-line error before any frame is written."""
    scene, workdir, _ = baked
    out = prt("render", scene, "--workdir", workdir, "--out", tmp_path / "q.exr",
              "--frames", "light:1:2", "-q")
    assert out.returncode == 0, out.stderr
    assert "lights[1] (quad; a light without geometry" in out.stdout
    assert "horizontal circle (xz plane) of radius" in out.stdout
    assert "centred on its corner (-0.5, 2.5, -0.5)" in out.stdout
    for spec, problem in (("light:7:2", "no light '7'"), ("light::2", "expected light[:LIGHT]:N")):
        bad = prt("render", scene, "--workdir", workdir, "--out", tmp_path / "b.exr",
                  "--frames", spec)
        assert bad.returncode == 2 and problem in bad.stderr, bad.stderr
        assert bad.stderr.count("\n") == 1
    assert not (tmp_path / "b.exr").exists()


def test_run_builds_one_renderer_for_its_frame_and_sequences(baked, tmp_path, monkeypatch):
    """`prt run` renders its frame and both sequences with one renderer (loading the
    artifacts once), and a run with every output up to date builds none; the frames are
    the ones a renderer of their own gives (the same arrays)."""
    scene_path, workdir, _ = baked
    scene = load_scene(scene_path)
    wd = job.workdir_for(scene, workdir)
    built = []
    own_renderer = job.frame_renderer

    def counted(*args, **kwargs):
        built.append(args[2])
        return own_renderer(*args, **kwargs)

    monkeypatch.setattr(job, "frame_renderer", counted)
    shared = tmp_path / "shared"
    _, frame, sequences = job.main_job(scene, wd, shared, None, (), 1, True)
    assert built == ["d2i"] and len(sequences) == 2
    job.main_job(scene, wd, shared, None, (), 1, True)
    assert built == ["d2i"]  # everything up to date: nothing built

    own = tmp_path / "own" / frame.exr.name  # each output with a renderer of its own
    job.render(scene, wd, "d2i", own, quiet=True)
    for seq in sequences:
        job.render_sequence(scene, wd, "d2i", f"{seq.kind}:8", own)
    assert len(built) == 4
    pairs = [(frame.exr, own)] + [(path, own.parent / path.name)
                                  for seq in sequences for path in seq.exr]
    assert len(pairs) == 17
    for ours, theirs in pairs:
        assert np.array_equal(read_exr(ours), read_exr(theirs)), ours.name


def test_run_skips_a_light_sequence_with_no_light_to_move(tmp_path):
    """A scene lit by a directional light only: `prt run` writes the frame and the
    gamma sequence, says the light sequence is skipped and why (before any frame is
    written), says so again on the next run instead of "up to date", and `prt status`
    shows it skipped; asking for it by name is an error."""
    doc = _d2i_doc(8)
    doc["lights"] = [{"type": "directional", "direction": [0.3, -1.0, 0.2],
                      "irradiance": [2.0, 2.0, 2.0]}]
    scene = load_scene(write_scene(tmp_path, doc))
    wd, frames = job.workdir_for(scene, tmp_path / "w"), tmp_path / "f"
    for _ in range(2):
        _, frame, sequences = job.main_job(scene, wd, frames, None, (), 1, True)
        assert frame.exr.is_file()
        skipped = {q.kind: q.skipped for q in sequences}
        assert "needs a light with a position" in skipped["light"]
        assert "directional" in skipped["light"] and skipped["gamma"] == ""
    assert not list(frames.glob("*_light_*"))
    states = {o.name: o.state for o in job.frame_states(scene, wd, frames,
                                                        job.status(scene, wd))}
    assert states == {"frame": "present", "sequence light:8": "skipped",
                      "sequence gamma:8": "present"}
    from pipeline.errors import PrtError

    with pytest.raises(PrtError, match="directional light; it has no position"):
        job.plan_sequence(scene, wd, "d2i", "light:0:2", frames / "x.exr")


def test_emitter_overlay_draws_a_moved_quad_where_it_is():
    """A camera at the origin looking down −z at a quad light facing it at z = −2 whose
    emitter object spans x, y ∈ [−0.5, 0.5]: in place, no light counts as moved; moved
    by +0.6 in x, the pixels it covers are those whose rays meet it (nearer than the
    wall behind at z = −3, not behind a surface at z = −1), on the right of the image."""
    size = 32
    camera = Camera((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 60.0, size, size)
    from pipeline.math.camera import camera_rays

    _, d = camera_rays(camera.position, camera.look_at, camera.up, camera.fov, size, size)
    d = d.reshape(-1, 3).astype(np.float64)
    wall = d * (-3.0 / d[:, 2:3])  # every pixel sees a wall at z = -3
    bounds = {"panel": (np.array([-0.5, -0.5, -2.0]), np.array([0.5, 0.5, -2.0]))}
    overlay = EmitterOverlay(camera, wall, np.zeros(size * size, np.int32), bounds)
    doc = small_scene_dict()
    doc["objects"]["panel"] = {"primitive": {"type": "plane", "size": [1, 1]},
                               "material": "grey"}
    doc["lights"] = [{"type": "quad", "corner": [-0.5, -0.5, -2.0], "edge_u": [1, 0, 0],
                      "edge_v": [0, 1, 0], "radiance": [5.0, 5.0, 5.0], "object": "panel"}]
    from pipeline.scene.file import scene_from_document

    scene = scene_from_document(__import__("pathlib").Path("s.yaml"), doc)
    rgb = np.zeros((size * size, 3), np.float32)
    assert moved_quads(scene, bounds) == [] and overlay.draw(rgb, scene) is rgb
    moved = with_light_offset(scene, 0, (0.6, 0.0, 0.0))
    assert moved_quads(moved, bounds) == [0]
    drawn = overlay.draw(rgb, moved).reshape(size, size, 3)
    hit = drawn[..., 0] == 5.0
    # expected: rays meeting z = -2 inside x ∈ [0.1, 1.1], y ∈ [-0.5, 0.5]
    p = d * (-2.0 / d[:, 2:3])
    expected = ((p[:, 0] >= 0.1) & (p[:, 0] <= 1.1) & (np.abs(p[:, 1]) <= 0.5)).reshape(
        size, size)
    np.testing.assert_array_equal(hit, expected)
    assert hit.sum() > 20 and hit[:, size // 2:].sum() == hit.sum()  # right half only
    near = EmitterOverlay(camera, d * (-1.0 / d[:, 2:3]), np.zeros(size * size, np.int32),
                          bounds)
    assert not (near.draw(rgb, moved) == 5.0).any()  # behind a nearer surface: hidden


def test_outputs_waiting_for_the_bake_name_their_own_files(tmp_path):
    """Before a bake, `prt status` lists the frame and each sequence as missing, waiting
    for the stages, each under its own file (a sequence under its record), not all
    under the frame's."""
    scene = load_scene(write_scene(tmp_path, _d2i_doc(8)))
    wd, frames = job.workdir_for(scene, tmp_path / "w"), tmp_path / "f"
    states = job.frame_states(scene, wd, frames, job.status(scene, wd))
    assert [(o.name, o.state, o.path.name) for o in states] == [
        ("frame", "missing", "tiny_d2i.exr"),
        ("sequence light:8", "missing", "tiny_d2i_light.json"),
        ("sequence gamma:8", "missing", "tiny_d2i_gamma.json")]
    assert all(o.reason.startswith("waits for ") for o in states)

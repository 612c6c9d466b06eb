"""Images a method cannot show right say so (issue 40 items 3 and 7): a mesh wound
inward and a camera inside a closed object, where triple's and sg's bakes (light on
the side a face's normal points to) differ from the two-sided reference, get a note
naming the objects; a preview far below the display range gets a note saying which
``--exposure`` shows it."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import write_scene
from tiny_scenes import tiny_scene

from pipeline import job
from pipeline.images import exposure_note
from pipeline.scene.file import load_scene

TETRAHEDRON = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
OUTWARD = [(1, 3, 2), (1, 2, 4), (1, 4, 3), (2, 3, 4)]


def _obj(path, inward: bool):
    faces = [(a, c, b) for a, b, c in OUTWARD] if inward else OUTWARD
    lines = [f"v {x} {y} {z}" for x, y, z in TETRAHEDRON * 0.8 + [-0.3, 0.0, 0.3]]
    path.write_text("\n".join(lines + [f"f {a} {b} {c}" for a, b, c in faces]) + "\n")
    return path


def _render(tmp_path, method: str, change) -> list[str]:
    import yaml

    scene = tiny_scene(tmp_path, method, size=12).path
    doc = yaml.safe_load(scene.read_text())
    change(doc, tmp_path)
    scene = load_scene(write_scene(scene.parent, doc))
    result = job.render(scene, job.workdir_for(scene, tmp_path / "w"), method,
                        tmp_path / "out.exr", quiet=True)
    return result.frame.notes


def _inward(inward: bool):
    def change(doc, folder):
        doc["objects"]["box"] = {"mesh": str(_obj(folder / "tetra.obj", inward)),
                                 "material": "red"}
    return change


def _inside(doc, folder):
    doc["camera"]["position"] = [0.6, 0.35, 0.2]  # the ball's centre
    doc["camera"]["look_at"] = [0.6, 0.35, 1.0]


@pytest.mark.parametrize("method", ["triple", "sg"])
def test_a_mesh_wound_inward_is_noted(tmp_path, method):
    """Issue 40 item 3: a closed mesh wound inward rendered black (triple) or nearly
    black (sg) without a word; the same mesh wound outward gets no note."""
    notes = _render(tmp_path / "in", method, _inward(True))
    assert any(n.startswith("box 100% of the pixels see the back of a face") and
               f"method {method} bakes light" in n for n in notes), notes
    assert not [n for n in _render(tmp_path / "out", method, _inward(False))
                if "back of a face" in n]


@pytest.mark.parametrize("method", ["triple", "sg"])
def test_a_camera_inside_a_closed_object_is_noted(tmp_path, method):
    """Issue 40 item 3: inside the ball (a closed sphere) triple and sg showed a lit
    interior (mean 0.059, 0.054) where the reference is 0."""
    notes = _render(tmp_path, method, _inside)
    assert any(n.startswith("ball 100% of the pixels see the back of a face")
               for n in notes), notes


def test_a_dark_preview_says_which_exposure_shows_it():
    """Issue 40 item 7: bunny_grace's default preview had a mean of 0.0019 and nothing
    said so. The note names the exposure that brings the mean luminance to middle grey
    (0.18) unless that pushes more than 1 % of the pixels past white."""
    dark = np.full((8, 8, 3), 0.0019, np.float32)
    assert exposure_note(dark, 0.0) == ("the preview is dark (mean luminance 0.0019 at +0 "
                                        "EV): --exposure 6 shows it")
    assert exposure_note(dark, 6.0) is None  # 0.0019 × 64 = 0.12 ≥ 0.18 / 16
    highlight = dark.copy()
    highlight[0, :2] = 0.05  # 3 % of the pixels: 2^4 × 0.05 = 0.8, 2^5 would clip them
    assert exposure_note(highlight, 0.0).endswith("--exposure 4 shows it")
    assert exposure_note(np.zeros((4, 4, 3), np.float32), 0.0) == \
        "the frame is black (no pixel has any light)"
    assert exposure_note(np.full((4, 4, 3), 0.2, np.float32), 0.0) is None

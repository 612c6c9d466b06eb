"""What the scene fuzzer's long run found (benchmarks/engine/fuzz.py), each case cut
down to the mutation that broke the invariant and kept as a regression test: it must
now exit 0 with a finite frame or exit 2 with one error line (tests/scene_fuzz.py)."""

from __future__ import annotations

from typing import Any

import pytest
from scene_fuzz import _base, obj_text, run_case


def _tiny_up(doc: dict[str, Any]) -> None:
    """seed 1, cases 115–116: an ``up`` of subnormal components passed validation and the
    camera frame divided a cross product of 1e-311 by itself (ValueError, exit 1)."""
    doc["camera"]["up"] = [-2.225073858507e-311, -2.225073858507e-311, 1e-300]


def _empty_grid(doc: dict[str, Any]) -> None:
    """seed 1, case 630: ``triple.frame_grid: []`` was a list as the default is, and
    Intel's OpenCL compiler crashed on the kernel it defined (exit −11). A list setting
    now has its default's length and element kind."""
    doc["settings"]["triple.frame_grid"] = []


def _mesh(kind: str, scale: float, offset: float):
    def change(doc: dict[str, Any]) -> None:
        doc["objects"]["box"] = {"mesh": "box.obj", "material": "red"}
    change.files = {"box.obj": obj_text(kind, scale, offset)}  # type: ignore[attr-defined]
    return change


# A mesh sweep (every OBJ kind of tests/scene_fuzz.py at scales 1e-6 and 1e4 and 1e5
# from the origin, each method) found, once the fuzzer wrote its OBJ numbers as plain
# floats:
# - far_object: a tetrahedron 1e5 units away made the ray offset (1e-4 of the scene's
#   diagonal) 10 units: d2i's and direct's shadow rays judged "in front of the light"
#   from the moved origin (black frames where the reference has 0.055), and d2i's
#   glossy transfer could not reshape zero gathers (exit 1);
# - huge_open: d2i wrote pixels of −1.8e-6 (truncated Haar rows of D L);
# - tiny_closed: triple's xatlas dropped every face of a tetrahedron 1e-6 wide.
def _tiny_view(doc: dict[str, Any]) -> None:
    """seed 1, case 719 and seed 2, case 929: a view direction and an up of subnormal
    length made the validation's sine 0/0 (a NumPy RuntimeWarning before the error line;
    here the scene renders)."""
    doc["camera"].update(position=[0.0, 0.0, 0.0], look_at=[0.0, 0.0, -1e-320],
                         up=[0.0, 1e-320, 0.0])


def _far_look_at(doc: dict[str, Any]) -> None:
    """A look_at whose difference from the position overflows float64: one line."""
    doc["camera"].update(position=[1e308, 0.0, 0.0], look_at=[-1e308, 0.0, 0.0])


def _mirror_ward(alpha: float, low: float):
    def change(doc: dict[str, Any]) -> None:
        """seed 3, cases 395–396: a ward_anisotropic roughness of 1e-12 (range from
        7e-124) fell between every sample of brdf_basis (a NumPy warning, then NaN
        refused mid-bake); roughness now stays above 5e-4, where the basis still sees
        the lobe."""
        doc["materials"]["shiny"] = {"model": "ward_anisotropic", "albedo": [0.4, 0.1, 0.1],
                                     "specular": 0.05, "gamma": alpha,
                                     "gamma_range": [low, 0.001]}
    return change


def _one_row_map(doc: dict[str, Any]) -> None:
    """seed 5, case 964: a 2 × 1 map (its rows at θ = π i/(H − 1)) divided by
    zero in triple's prefilter (exit 1); a map now has at least 2 rows."""
    doc["lights"] = [{"type": "environment", "file": "one_row.exr"}]


_one_row_map.files = {"one_row.exr": ["map", "plain", 1]}  # type: ignore[attr-defined]


FOUND = {"tiny_up": ("triple", _tiny_up, "exit0"),
         "one_row_map": ("triple", _one_row_map, "exit2"),
         "mirror_ward": ("d2i", _mirror_ward(1e-12, 7e-124), "exit2"),
         "sharpest_ward": ("d2i", _mirror_ward(6e-4, 5.5e-4), "exit0"),
         "tiny_view": ("direct", _tiny_view, "exit0"),
         "far_look_at": ("direct", _far_look_at, "exit2"),
         "empty_grid": ("triple", _empty_grid, "exit2"),
         "far_object": ("d2i", _mesh("closed", 0.5, 1e5), "exit0"),
         "far_object_direct": ("direct", _mesh("closed", 0.5, 1e5), "exit0"),
         "huge_open": ("d2i", _mesh("open", 1e4, 0.0), "exit0"),
         "tiny_closed": ("triple", _mesh("closed", 1e-6, 0.0), "exit0")}


@pytest.mark.parametrize("name", sorted(FOUND))
def test_a_fuzzer_finding_keeps_the_invariant(tmp_path, name: str) -> None:
    method, change, expected = FOUND[name]
    case = _base(method, 6)
    change(case.doc)
    case.files.update(getattr(change, "files", {}))
    outcome = run_case(case, tmp_path)
    assert (outcome.kind, outcome.problem) == (expected, ""), outcome
    if name.startswith("far_object"):  # lit: `prt reference --transport direct` has 0.055
        from pipeline.images import read_exr

        assert read_exr(tmp_path / "frame.exr").mean() > 0.04

"""The README's checkable statements against the code (issue 40 item 8: the README said
``specular`` defaults to 0.5 and that editing γ re-bakes d2i's PCA basis; ``prt
methods`` and ``prt render --help`` named only ``rotate:N`` for triple)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline import job
from pipeline.engine.graph import with_upstream
from pipeline.math.brdf import MATERIAL_PARAMETERS
from pipeline.registry import get_method, registry

README = (Path(__file__).resolve().parent.parent / "README.md").read_text()


def _flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def test_the_material_defaults_the_readme_states():
    default = {p.name: p.default for p in MATERIAL_PARAMETERS["blinn_phong"].params}
    stated = re.search(r"`specular` \(ρs, default ([0-9.]+)\)", README)
    assert stated and float(stated[1]) == default["specular"]
    assert f"`specular` defaults to {default['specular']}" in README


def test_every_sequence_form_is_in_the_readme_methods_and_render_help():
    help_text = _flat(subprocess.run([sys.executable, "-m", "pipeline", "render", "--help"],
                                     capture_output=True, text=True).stdout)
    methods_text = subprocess.run([sys.executable, "-m", "pipeline", "methods"],
                                  capture_output=True, text=True).stdout
    for name, m in registry().items():
        for form in m.sequence_forms:
            assert f"`{form}`" in README, (name, form)
            assert form in help_text, (name, form)
        if m.sequence_forms:
            assert f"sequences (--frames): {', '.join(m.sequence_forms)}" in methods_text


def _readers(method: str, key: str) -> set[str]:
    """The stages a method's frames depend on that read ``materials.*.<key>``."""
    graph = job.stages()
    baked = with_upstream(graph, list(get_method(method).reads))
    return {s for s in baked if f"materials.*.{key}" in graph.stages[s].scene}


@pytest.mark.parametrize(("method", "key", "stages"), [
    ("d2i", "gamma", set()), ("d2i", "specular", set()), ("d2i", "albedo", set()),
    ("d2i", "gamma_range", {"brdf_basis"}),
    ("triple", "gamma", {"triple.brdf_tables"}), ("sg", "gamma", set())])
def test_what_a_material_edit_re_bakes_is_what_the_readme_says(method, key, stages):
    """"editing one material's γ range re-bakes that material's PCA basis ... its γ, ρs
    and albedo re-bake nothing of d2i ... its γ re-bakes its BRDF table (triple) and
    nothing of sg's default": a stage re-bakes on an edit of a scene key exactly when it
    declares it (its key holds the declared sections: tests/test_incremental.py)."""
    text = _flat(README)
    assert "material's γ range re-bakes that material's PCA basis" in text
    assert "its γ, ρs and albedo re-bake nothing of d2i" in text
    assert "its γ re-bakes its BRDF table (triple) and nothing of sg's default" in text
    assert _readers(method, key) == stages

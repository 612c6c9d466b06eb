"""Reference images kept in the work directory: ``prt reference`` and ``prt evaluate``
render one (pipeline/evaluation/reference.py) only when no artifact with its key is
stored under ``WORKDIR/reference/``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.engine.codeversion import code_version
from pipeline.engine.keys import digest
from pipeline.engine.schema import load_schema
from pipeline.engine.store import (
    Workdir,
    open_artifact,
    read_record,
    software_versions,
    write_artifact,
)
from pipeline.evaluation import reference as ref
from pipeline.job import load_geometry
from pipeline.scene.model import Scene


@dataclass
class ReferenceResult:
    """A reference image (from the cache or rendered now) and where it is stored."""

    image: ref.ReferenceImage
    artifact: Path
    cached: bool


def reference(scene: Scene, workdir: Workdir, settings: Any, quiet: bool = False
              ) -> ReferenceResult:
    """The reference image for ``settings`` (a ReferenceSettings), rendered unless an
    artifact with the same key (scene camera, lights and materials, the geometry's
    bytes, renderer code, settings) is stored under ``workdir/reference/``."""
    geometry, geometry_digest = load_geometry(scene, workdir, quiet)
    parts = {"code": code_version(["pipeline.evaluation.reference"]),
             "geometry": geometry_digest, "settings": dataclasses.asdict(settings),
             "scene": {s: scene.section(s) for s in ("camera", "lights", "materials")}}
    key = digest(parts)
    lobe = "" if settings.lobe == "all" else f"-{settings.lobe}"
    path = workdir.root / "reference" / f"{settings.transport}{lobe}-{key[:16]}.zarr"
    record = read_record(path)
    if record is not None and record.get("key") == key:
        stored = open_artifact(path, "reference")
        a = stored.attrs
        image = ref.ReferenceImage(stored.read("mean"), stored.read("variance"), a["spp"],
                                   a["estimate"], a["seconds"], a["rays"],
                                   [tuple(h) for h in a["history"]])
        return ReferenceResult(image, path, True)
    image = ref.render(scene, geometry, settings, progress=not quiet)
    with workdir.lock():
        write_artifact(workdir, path, load_schema("reference"),
                       {"mean": image.mean, "variance": image.variance},
                       {"transport": settings.transport,
                        "settings": dataclasses.asdict(settings), "spp": image.spp,
                        "estimate": float(image.estimate), "seconds": image.seconds,
                        "rays": int(image.rays),
                        "history": [list(map(float, h)) for h in image.history]},
                       {"stage": "reference", "key": key, "key_parts": parts,
                        "seconds": image.seconds, "software": software_versions()},
                       {"tile": 64})
    return ReferenceResult(image, path, False)

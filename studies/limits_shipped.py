"""Which declared limits (pipeline/method.py ``Limit``) warn on the shipped scenes: each
scene (optionally ``@SIZE`` for a square size) has the cheap stages its checks read baked
into ``--workdir`` (triple: the atlas; sg: the geometry; d2i: the gathers), then its
methods' limits run before and after the bake (decision 0038).

    python studies/limits_shipped.py --workdir W scenes/bunny_sg.yaml scenes/bunny_sg.yaml@128 ...
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline import job
from pipeline.engine.store import open_artifact
from pipeline.registry import limit_warnings, scene_methods

UNTIL = {"triple": ("triple.atlas",), "sg": ("geometry",), "d2i": ("d2i.gather",)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="+", help="SCENE.yaml or SCENE.yaml@SIZE")
    parser.add_argument("--workdir", type=Path, required=True)
    args = parser.parse_args()
    graph = job.stages()
    for item in args.scenes:
        name, _, size = item.partition("@")
        scene = job.open_scene(Path(name), (int(size), int(size)) if size else None)
        for method in scene_methods(scene):
            workdir = job.workdir_for(scene, args.workdir / scene.name)
            before = limit_warnings(method, scene)
            job.bake(scene, workdir, until=UNTIL.get(method.name), quiet=True)
            artifacts = {s: open_artifact(workdir.artifact(s), graph.stages[s].output)
                         for s in method.reads if workdir.artifact(s).exists()}
            found = list(dict.fromkeys(before + limit_warnings(method, scene, artifacts)))
            size_text = f"{scene.camera.width}x{scene.camera.height}"
            print(f"{item} [{method.name} {size_text}]: " + ("silent" if not found else
                                                           "\n  " + "\n  ".join(found)))


if __name__ == "__main__":
    main()

"""The stage DAG: edges from each stage to the stages whose artifacts it reads."""

from __future__ import annotations

from graphlib import CycleError, TopologicalSorter

from pipeline.engine.stagefile import StageFile
from pipeline.errors import PrtError


def topological_order(stagefile: StageFile) -> list[str]:
    """Stages ordered so that every stage comes after its inputs; ties keep file order."""
    order = list(stagefile.stages)
    sorter = TopologicalSorter({name: stagefile.stages[name].inputs for name in order})
    try:
        sorter.prepare()
    except CycleError as exc:
        cycle = " -> ".join(exc.args[1])
        raise PrtError(stagefile.path, f"stage inputs form a cycle: {cycle}") from None
    result: list[str] = []
    while sorter.is_active():
        ready = sorted(sorter.get_ready(), key=order.index)
        result.extend(ready)
        sorter.done(*ready)
    return result


def with_upstream(stagefile: StageFile, targets: list[str]) -> set[str]:
    """``targets`` and every stage they depend on, directly or not."""
    seen: set[str] = set()
    stack = list(targets)
    while stack:
        name = stack.pop()
        if name not in stagefile.stages:
            raise PrtError(stagefile.path, f"unknown stage {name!r} (stages: "
                           f"{', '.join(stagefile.stages)})")
        if name not in seen:
            seen.add(name)
            stack.extend(stagefile.stages[name].inputs)
    return seen


def dependent_on(stagefile: StageFile, section: str) -> set[str]:
    """The stages whose artifacts depend on the scene's ``section`` (``camera``,
    ``environment``): those that read it or a key under it, and every stage downstream
    of one."""
    out: set[str] = set()
    for name in topological_order(stagefile):
        spec = stagefile.stages[name]
        if any(s == section or s.startswith(f"{section}.") for s in spec.scene) or \
                any(dep in out for dep in spec.inputs):
            out.add(name)
    return out

"""Report on baked ``sg.fit`` / ``sg.relax`` artifacts (method sg, issue 17): what the
stages' own counts leave out, measured on the stored lobes.

Run from the project root:
    python studies/sg_fit_report.py --workdir W [--stage sg.relax|sg.fit] [--out F.json]
(W: a work directory holding ``geometry``, ``sg.fit`` and ``sg.relax``, e.g.
.prt/bunny_sg or an evaluate sweep's .prt/eval_sg/sweep/sg). Writes the JSON and a PNG
beside it.

- **Lobe counts** per glossy object (N chosen from ``sg.fit_tolerance``).
- **Grazing views**: the fit's relative L² error (stored per vertex and view) against
  cos θ = n·ω_view, the view's elevation over the vertex's tangent plane, in bins
  (median and 90th percentile): where the lobes stop fitting the transport.
- **Flips over every mesh edge**: sg.fit counts and relaxes flips within its vertex
  batches (``sg.fit_batch``), sg.relax over every edge; here the same count
  (sg_coherence.count_flips, all slots, and by more than 5°) over the edges inside
  batches and over the edges that cross batch boundaries, for the chosen artifact.
- **Bake time**: the recorded seconds of sg.fit and sg.relax, per chunk (each chunk on
  one core).
- **Storage** against paper 003's 92·7·M·N floats (M vertices, N lobes): the stored
  arrays' bytes (the slots each vertex stores), their bytes on disk (zarr-compressed),
  and the formula at N = 1 and at the mean stored N.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline.engine.store import Workdir, open_artifact  # noqa: E402
from pipeline.methods.sg import coherence as sg_coherence  # noqa: E402
from pipeline.methods.sg.stages import fit as stage  # noqa: E402

COS_BINS = np.array([0.0, 0.1, 0.2, 0.3, 0.5, 0.7, 0.9, 1.0])


def bytes_on_disk(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", required=True, help="work directory with sg.fit baked")
    ap.add_argument("--stage", default="sg.relax", choices=["sg.fit", "sg.relax"],
                    help="the lobes as fitted (batches relaxed apart) or as rendered")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/sg_fit_report.json"))
    args = ap.parse_args()
    wd = Workdir(args.workdir)
    geometry = open_artifact(wd.artifact("geometry"), "geometry")
    fit = open_artifact(wd.artifact(args.stage), "sg_lobes")
    batch = int(open_artifact(wd.artifact("sg.fit"), "sg_lobes")
                .record["key_parts"]["params"]["sg.fit_batch"])
    rows, first = fit.read("lobes"), fit.read("first")
    count, error = fit.read("count"), fit.read("error")
    stored = stage.slot_counts(first, len(rows))
    lobes = stage.unpack_slots(rows, first, stored)
    views = fit.read("views")
    normals = geometry.read("normals").astype(np.float64)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    faces = geometry.read("faces")
    ranges = geometry.read("object_ranges")
    view_nbs = sg_coherence.view_neighbours(views)
    report: dict = {"workdir": str(args.workdir), "stage": args.stage,
                    "tolerance": fit.attrs["tolerance"],
                    "grid": fit.attrs["grid"], "batch": batch, "objects": {}}
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, (v0, v1, _, _) in zip(geometry.attrs["object_names"], ranges, strict=True):
        n = count[v0:v1].astype(np.int64)
        if not n.any():
            continue
        err = error[v0:v1]
        active = err >= 0
        cos = normals[v0:v1] @ views.T                                   # (P, 92)
        bins = []
        for lo, hi in zip(COS_BINS[:-1], COS_BINS[1:], strict=True):
            e = err[active & (cos > lo) & (cos <= hi)]
            bins.append({"cos_from": float(lo), "cos_to": float(hi), "functions": int(e.size),
                         "median": float(np.median(e)) if e.size else None,
                         "p90": float(np.percentile(e, 90)) if e.size else None})
        edges = stage.batch_edges(faces, v0, v1)
        across = (edges[:, 0] // batch) != (edges[:, 1] // batch)
        mean = lobes[v0:v1, ..., 3:6].astype(np.float64)
        no_views = [np.array([], np.int64)] * len(views)
        flips = {"within_batches": sg_coherence.count_flips(mean, active, n, edges[~across],
                                                            no_views),
                 "across_batches": sg_coherence.count_flips(mean, active, n, edges[across],
                                                            no_views),
                 "between_views": sg_coherence.count_flips(mean, active, n,
                                                           edges[:0], view_nbs)}
        m, mean_n = int(v1 - v0), float(n.mean())
        report["objects"][name] = {
            "vertices": int(m), "counts": np.bincount(n, minlength=4).tolist(),
            "error_median": float(np.median(err[active])),
            "error_p90": float(np.percentile(err[active], 90)),
            "error_by_view_elevation": bins, "edges": len(edges),
            "edges_across_batches": int(across.sum()), "flips": flips,
            "storage": {
                "paper_floats_n1": 92 * 7 * m, "paper_bytes_n1": 4 * 92 * 7 * m,
                "paper_bytes_mean_n": 4 * 92 * 7 * m * mean_n, "mean_n": mean_n,
                "stored_slots": int(stored[v0:v1].sum()),
                "stored_array_bytes": int(rows[0].nbytes * stored[v0:v1].sum()
                                          + first[v0:v1].nbytes + count[v0:v1].nbytes
                                          + error[v0:v1].nbytes)}}
        centres = 0.5 * (COS_BINS[:-1] + COS_BINS[1:])
        ax.plot(centres, [b["median"] for b in bins], "o-", label=f"{name}: median")
        ax.plot(centres, [b["p90"] for b in bins], "s--", label=f"{name}: 90th percentile")
    report["bytes_on_disk"] = bytes_on_disk(wd.artifact(args.stage))
    for stage_name in ("sg.fit", "sg.relax"):
        record = open_artifact(wd.artifact(stage_name), "sg_lobes").record
        report[stage_name] = {"seconds": record.get("seconds"),
                              "chunk_seconds": record.get("chunk_seconds")}
    ax.set_xlabel("cos θ of the view over the vertex's tangent plane (0: grazing)")
    ax.set_ylabel("relative L² error of the fit")
    ax.set_title(f"{args.stage} errors by view elevation (tolerance {fit.attrs['tolerance']})")
    ax.grid(alpha=0.3)
    ax.legend()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=120)
    out.write_text(json.dumps(report, indent=1))
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()

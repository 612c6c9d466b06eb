"""Study: the dense top-only path's two ways at 80 coefficients (issue 16, "Rendering").

Rows cut top-only to 80 are functions constant on the 80 level-1 triangles. Either the
rows are turned into triangle values once (pipeline/methods/triple/dense.py, the shipped
kernel ``triple_shade_dense``), or every pixel sums the sparse rows' coefficients
densely and inverts them itself (the kernel below, kept here only for this comparison).
Both on the same G-buffer, launched interleaved: median device ms and process CPU ms
(all threads; on a contended machine the fairer figure), and the largest difference of
the two results relative to the largest pixel (float32: ~1e-6 expected).

Run from the project root: python studies/triple_dense_inverse.py WORKDIR [--size 256]
(WORKDIR: a bunny_grace bake at its own size). Writes
benchmarks/results/triple_dense_inverse.json.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

INVERSE_KERNEL = """
#define SW_ROWS 9
#include "sphwavelet.h"
#include "triple_lookup.h"
__kernel void inverse80(__global const uint* ls, __global const ushort* li,
                        __global const float* lv, __global const uint* vs,
                        __global const ushort* vi, __global const float* vv,
                        __global const uint* bs, __global const ushort* bi,
                        __global const float* bv, __global const float* root_area,
                        __global const float* wavelet, __global const float* tri_area,
                        TRIPLE_GBUFFER_ARGS, const int n, __global float* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    TRIPLE_LOOKUP(i, g, look);
    float3 cl[80], cb[80];
    float cv[80];
    for (int k = 0; k < 80; ++k) { cl[k] = (float3)(0.0f); cv[k] = 0.0f; cb[k] = (float3)(0.0f); }
    for (int r = 0; r < 8; ++r) {
        float w = look.light_weight[r];
        if (w == 0.0f) continue;
        for (uint e = ls[look.light_rows[r]]; e < ls[look.light_rows[r] + 1]; ++e)
            cl[li[e]] += w * vload3(e, lv);
    }
    for (int r = 0; r < 4; ++r) {
        float w = look.vis_weight[r];
        if (w == 0.0f) continue;
        for (uint e = vs[look.vis_rows[r]]; e < vs[look.vis_rows[r] + 1]; ++e)
            cv[vi[e]] += w * vv[e];
    }
    for (int r = 0; r < 9; ++r) {
        float3 w = look.brdf_weight[r];
        if (w.x == 0.0f && w.y == 0.0f && w.z == 0.0f) continue;
        for (uint e = bs[look.brdf_rows[r]]; e < bs[look.brdf_rows[r] + 1]; ++e)
            cb[bi[e]] += w * bv[e];
    }
    float3 total = (float3)(0.0f);
    for (int root = 0; root < 20; ++root) {  /* inverse transform to the level-1 values */
        float inv = rsqrt(root_area[root]);
        float3 l0 = cl[root] * inv, b0 = cb[root] * inv;
        float v0 = cv[root] * inv;
        __global const float* w = wavelet + 12 * root;
        for (int c = 0; c < 4; ++c) {
            float3 l = l0, b = b0;
            float v = v0;
            for (int t = 0; t < 3; ++t) {
                float x = w[4 * t + c];
                int k = 20 + 3 * root + t;
                l += cl[k] * x;
                b += cb[k] * x;
                v += cv[k] * x;
            }
            total += tri_area[4 * root + c] * v * l * b;
        }
    }
    vstore3(total, i, out);
}
"""


def cpu_ms() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return (usage.ru_utime + usage.ru_stime) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("workdir", type=Path)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    import pyopencl as pcl

    from pipeline import job
    from pipeline.device import cl
    from pipeline.device.raytrace import Mesh, RayTracer
    from pipeline.math.brdf import scene_brdfs
    from pipeline.math.sphwavelet import kernel_tables
    from pipeline.methods.triple import render
    from pipeline.methods.triple.dense import DenseTables, _level_matrix
    from pipeline.methods.triple.gbuffer import LookupTables, kernel_arguments
    from pipeline.registry import get_method
    from pipeline.render import WORK_GROUP
    from pipeline.render.surface_detail import SceneDetail

    scene = job.open_scene(ROOT / "scenes" / "bunny_grace.yaml")
    artifacts = job.method_artifacts(get_method("triple"), job.workdir_for(scene, args.workdir))
    names = artifacts["geometry"].attrs["material_names"]
    tables, atlas = render.load_tables(artifacts, names)
    tables = tables.truncated("top-only", 80)
    dense = DenseTables.from_tables(tables, 1)
    geo = artifacts["geometry"]
    arrays = {n: geo.read(n) for n in
              ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
    cam = scene.with_image_size(args.size, args.size).camera
    gbuffer = render.camera_gbuffer(RayTracer(arrays["vertices"], arrays["faces"]),
                                    Mesh.from_arrays(arrays), atlas,
                                    SceneDetail(scene, names), cam)
    brdfs = scene_brdfs(scene, names)
    lookup = LookupTables.of(tables, atlas, np.array([b.albedo for b in brdfs]),
                             np.array([b.specular for b in brdfs]))
    args_common = kernel_arguments(gbuffer, tables, lookup, 0.3, {})
    n = gbuffer.count
    basis = kernel_tables(tables.basis)
    _, tri_area = _level_matrix(tables.basis.leaf_level, 1)
    sparse = [b for t in (tables.light, tables.visibility, tables.brdf) for b in t.device]
    sparse += [cl.read_only_buffer(a) for a in (basis["root_area"], basis["wavelet"],
                                                tri_area.astype(np.float32))]
    kernel_dir = str(ROOT / "kernels")
    macros = (ROOT / "kernels" / "triple.cl").read_text()
    macros = macros[macros.index("#define TRIPLE_GBUFFER_ARGS"):
                    macros.index("/* Per camera: the grid coordinates")]
    source = INVERSE_KERNEL.replace('#include "triple_lookup.h"',
                                    '#include "triple_lookup.h"\n' + macros)
    inverse = pcl.Program(cl.context(), source).build(
        options=["-I", kernel_dir, f"-DSW_LEVELS={tables.basis.leaf_level}"]).inverse80
    shipped = cl.kernel("triple.cl", "triple_shade_dense",
                        {"SW_LEVELS": tables.basis.leaf_level, "TRIPLE_T": 80, "TRIPLE_W": 8})
    runs = {"convert_once": (shipped, [*dense.device, *args_common]),
            "inverse_per_pixel": (inverse, [*sparse, *args_common])}
    times = {k: {"ms": [], "cpu_ms": []} for k in runs}
    results = {}
    for _ in range(args.repeats):
        for name, (kernel, kargs) in runs.items():
            out = np.empty((n, 3), np.float32)
            c0 = cpu_ms()
            ms = cl.run(kernel, n, *kargs, np.int32(n), out=out, local=WORK_GROUP)
            times[name]["cpu_ms"].append(cpu_ms() - c0)
            times[name]["ms"].append(ms)
            results[name] = out
    diff = np.abs(results["convert_once"] - results["inverse_per_pixel"]).max() \
        / np.abs(results["convert_once"]).max()
    summary = {"pixels": n, "size": args.size, "repeats": args.repeats,
               "load_average": os.getloadavg(), "max_relative_difference": float(diff),
               **{k: {"median_ms": statistics.median(v["ms"]),
                      "median_cpu_ms": statistics.median(v["cpu_ms"]), **v}
                  for k, v in times.items()}}
    summary["cpu_ratio_inverse_over_convert"] = \
        summary["inverse_per_pixel"]["median_cpu_ms"] / summary["convert_once"]["median_cpu_ms"]
    out_path = ROOT / "benchmarks" / "results" / "triple_dense_inverse.json"
    out_path.write_text(json.dumps(summary, indent=1))
    print(json.dumps({k: v for k, v in summary.items() if not isinstance(v, dict)}),
          {k: (round(summary[k]["median_ms"], 1), round(summary[k]["median_cpu_ms"], 1))
           for k in runs})


if __name__ == "__main__":
    main()

"""kernels/fastmath.h (exp, log1p and atan2 without libm calls, for kernels that PoCL
should vectorise) against NumPy's float64 exp / log1p / arctan2 of the same float32
inputs."""

from __future__ import annotations

import numpy as np

SOURCE = """
#include "fastmath.h"
__kernel void fastmath_eval(__global const float* x, __global float* e,
                            __global float* l) {
    int i = get_global_id(0);
    e[i] = fast_exp(x[i]);
    l[i] = fast_log1p(x[i]);
}
"""


def _run(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import pyopencl as cl_

    from pipeline.device import cl

    program = cl_.Program(cl.context(), SOURCE).build(options=["-I", str(cl.kernel_dir())])
    e, lg = np.empty_like(x), np.empty_like(x)
    e_buf, l_buf = (cl_.Buffer(cl.context(), cl_.mem_flags.WRITE_ONLY, x.nbytes)
                    for _ in range(2))
    program.fastmath_eval(cl.queue(), x.shape, None, cl.read_only_buffer(x), e_buf, l_buf)
    cl_.enqueue_copy(cl.queue(), e, e_buf)
    cl_.enqueue_copy(cl.queue(), lg, l_buf)
    return e, lg


def test_fast_exp_and_log1p_match_float64_to_a_few_ulp():
    """Relative error ≤ 4e-7 (≈ 3.4 float32 ulp; measured 0.8e-7 for exp, 1.6e-7 for
    log1p: Cephes' polynomials are accurate to ~1 ulp, plus the rounding of their
    float32 evaluation), over exp's whole normal
    range and log1p from −1 + 2^-23 to 1e30, with tiny arguments (log1p(x) = x), and the
    ends: exp below −87.34 is 0, above 88.72 +inf; log1p(+inf) = +inf."""
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(-87.3, 88.7, 20000), -np.logspace(-30, -1e-7, 2000),
                        np.logspace(-30, 1, 2000), [0.0, -1.0 + 2.0 ** -23, 1e30]])
    x = x.astype(np.float32)
    e, lg = _run(x)
    in_range = (x > -87.3) & (x < 88.7)
    exact = np.exp(x[in_range].astype(np.float64))
    assert np.all(np.abs(e[in_range] - exact) <= 4e-7 * exact)
    domain = x > -1.0
    exact_log = np.log1p(x[domain].astype(np.float64))
    assert np.all(np.abs(lg[domain] - exact_log) <= 4e-7 * np.abs(exact_log))
    ends = np.array([-88.0, -1e30, 89.0, np.inf], np.float32)
    e_end, l_end = _run(ends)
    assert np.array_equal(e_end, [0.0, 0.0, np.inf, np.inf])
    assert l_end[-1] == np.inf


ATAN2_SOURCE = """
#include "fastmath.h"
__kernel void atan2_eval(__global const float* y, __global const float* x,
                         __global float* out) {
    int i = get_global_id(0);
    out[i] = fast_atan2(y[i], x[i]);
}
"""


def test_fast_atan2_matches_float64_to_its_stated_bound():
    """Within 1e-6 rad of float64 arctan2 (the minimax polynomial's error plus float32
    evaluation and rounding, whose ulp at π is 2.4e-7; measured 9.0e-7) in all four
    quadrants, over
    directions at every scale, on the axes and at (0, 0), where it is 0; and relative
    error ≤ 1e-6 for small angles (the BRDF coordinate δ near the mirror direction)."""
    import pyopencl as cl_

    from pipeline.device import cl

    rng = np.random.default_rng(5)
    angle = rng.uniform(-np.pi, np.pi, 200000)
    radius = 10.0 ** rng.uniform(-20, 20, len(angle))
    small = 10.0 ** rng.uniform(-7, -1, 20000)
    y = np.concatenate([radius * np.sin(angle), small, [0, 0, 1, -1, 0]]).astype(np.float32)
    x = np.concatenate([radius * np.cos(angle), np.ones_like(small), [0, 1, 0, 0, -1]]
                       ).astype(np.float32)
    program = cl_.Program(cl.context(), ATAN2_SOURCE).build(
        options=["-I", str(cl.kernel_dir())])
    out = np.empty_like(x)
    out_buf = cl_.Buffer(cl.context(), cl_.mem_flags.WRITE_ONLY, out.nbytes)
    program.atan2_eval(cl.queue(), x.shape, None, cl.read_only_buffer(y),
                       cl.read_only_buffer(x), out_buf)
    cl_.enqueue_copy(cl.queue(), out, out_buf)
    exact = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    assert np.max(np.abs(out - exact)) <= 1e-6
    tiny = slice(len(angle), len(angle) + len(small))
    assert np.all(np.abs(out[tiny] - exact[tiny]) <= 1e-6 * exact[tiny])
    assert out[-5] == 0.0

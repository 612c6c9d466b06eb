/* PRT_SCALAR_ITEMS: a kernel attribute for kernels whose work-items run loops of
 * data-dependent length (sparse merges, a row's own entry count, a radix select).
 *
 * Intel's CPU runtime vectorises a kernel across work-items (16 lanes on AVX-512): lanes
 * whose loops end early wait, masked, for the longest, so such kernels ran several
 * times slower there than on PoCL (triple's stored-rows product 2577 ms against 480 ms
 * for a 64² frame of bunny_grace; the rotation grid's wavelet transform 7×). A
 * vec_type_hint of a 4-wide type tells a compiler the kernel's arithmetic is vectorised
 * already; Intel's then runs the work-items one by one (measured on the same launches:
 * 266 ms, and the transform at PoCL's speed). A hint only: PoCL and NVIDIA's compiler
 * are free to ignore it, and the results are the kernels' own either way
 * (benchmarks/engine/opencl_cpus.py, decision 0002). */
#ifndef PRT_VECTORIZE_H
#define PRT_VECTORIZE_H

#define PRT_SCALAR_ITEMS __attribute__((vec_type_hint(float4)))

#endif

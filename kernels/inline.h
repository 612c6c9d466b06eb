/* PRT_INLINE: how every helper function of the kernels is declared (force-inlined).
 *
 * Intel's OpenCL CPU runtime (2026.2) miscompiles a call that is not inlined when a
 * 3-component vector (float3, int3) is passed or returned by value and the caller is
 * vectorised across work-items: every lane but the first reads the vectors 12 bytes
 * apart where they lie 16 bytes apart, so it gets its neighbour's components (the
 * direct and d2i frames came out as garbage, in stripes of 16 pixels). Four lines show
 * it: `__attribute__((noinline)) float3 f(float x) { return (float3)(x, 2*x, 3*x); }`
 * called from a kernel that stores f(a[i]) gives lane 1 (0, 1, 2) for (1, 2, 3). A call
 * that is inlined is compiled right, and `inline` alone lets the compiler decide (it
 * declined for functions called from two kernels of one program). So every function
 * that takes or returns a 3-component vector by value is declared PRT_INLINE
 * (tests/test_kernel_sources.py checks every kernel folder). Not every function: forced
 * inlining of the radix select's 2 KB private histograms (kernels/triple/wavelet_select.cl)
 * overflowed a PoCL thread's stack, so the others keep `inline`
 * (decision 0001). */
#ifndef PRT_INLINE_H
#define PRT_INLINE_H

#define PRT_INLINE inline __attribute__((always_inline))

#endif

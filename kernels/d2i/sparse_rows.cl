/* Sparse Haar rows against a radiance vector (paper 000 eq. 17 and the per-pixel products
 * of eq. 9): rows are CSR (offsets[r] .. offsets[r + 1] into index / value); radiance is
 * float4 (RGB, w unused) per entry of the renderer's radiance vector.
 *
 * Defines: INDEX_T = the type of the row indices (ushort where the radiance vector has
 *          at most 2^16 entries, else int); VALUE_HALF = 1 where values are float16 over
 *          a float32 scale per row (pipeline/engine/rows.py quantise_values: 4 bytes per entry
 *          instead of 6), 0 for float32 values (scale unused). */

#if VALUE_HALF
#define ROW_VALUE(e) vload_half((e), value)
typedef half row_value_t;
#else
#define ROW_VALUE(e) value[e]
typedef float row_value_t;
#endif

/* out[r] = sum over row r of value * radiance[index]  (one work-item per row), times
 * the row's scale. Four independent partial sums, four entries per step: one
 * accumulator would chain every add on the previous one (latency-bound: 45 against 25
 * ms for the 400² bake's D rows on PoCL's CPU device), so the loop keeps several loads
 * in flight; it then streams the rows at about three quarters of the copy probe's rate
 * (benchmarks/d2i/frames.py). Written as mul + add: fma() was slower on PoCL. */
__kernel void sparse_rows(__global const int* offsets, __global const INDEX_T* index,
                          __global const row_value_t* value, __global const float* scale,
                          __global const float4* radiance, const int rows,
                          __global float4* out)
{
    int r = get_global_id(0);
    if (r >= rows) return;
    float4 a0 = (float4)(0.0f), a1 = a0, a2 = a0, a3 = a0;
    int e = offsets[r], end = offsets[r + 1];
    for (; e + 4 <= end; e += 4) {
        a0 += ROW_VALUE(e) * radiance[index[e]];
        a1 += ROW_VALUE(e + 1) * radiance[index[e + 1]];
        a2 += ROW_VALUE(e + 2) * radiance[index[e + 2]];
        a3 += ROW_VALUE(e + 3) * radiance[index[e + 3]];
    }
    for (; e < end; ++e) a0 += ROW_VALUE(e) * radiance[index[e]];
    float4 sum = (a0 + a1) + (a2 + a3);
#if VALUE_HALF
    sum *= scale[r];
#endif
    out[r] = sum;
}

/* The same products with one work-group of SPARSE_GROUP work-items per row (a GPU's
 * layout, d2i.py): the items read the row's entries SPARSE_GROUP apart, so neighbouring
 * items touch neighbouring addresses (coalesced; one item per row reads rows ≈ 2 kB
 * apart), keep a partial sum each, and add them up in local memory. Global size rows ·
 * SPARSE_GROUP, local SPARSE_GROUP (a power of two). */
__kernel void sparse_rows_grouped(__global const int* offsets, __global const INDEX_T* index,
                                  __global const row_value_t* value,
                                  __global const float* scale,
                                  __global const float4* radiance, const int rows,
                                  __global float4* out)
{
    __local float4 partial[SPARSE_GROUP];
    int r = get_group_id(0), l = get_local_id(0);
    float4 a = (float4)(0.0f);
    if (r < rows)
        for (int e = offsets[r] + l, end = offsets[r + 1]; e < end; e += SPARSE_GROUP)
            a += ROW_VALUE(e) * radiance[index[e]];
    partial[l] = a;
    for (int step = SPARSE_GROUP / 2; step > 0; step >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (l < step) partial[l] += partial[l + step];
    }
    if (l == 0 && r < rows) {
        float4 sum = partial[0];
#if VALUE_HALF
        sum *= scale[r];
#endif
        out[r] = sum;
    }
}

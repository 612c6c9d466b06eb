/* The stored rows of many coefficient rows at once: the OpenCL twin of
 * pipeline/math/wavelet_rows.py select_rows (the rule in its docstring), for method
 * triple's lighting and BRDF tables (launchers: pipeline/wavelet_select_cl.py).
 *
 * Row r (of rows first_row .. first_row + R - 1 of coeffs, laid out (rows, CHANNELS, n))
 * has energies e_i = sum_c w_c c_ic^2 (float32, channel by channel, no FMA: the
 * NumPy twin's rounding), total E. The head i < keep_first keeps every e_i > 0; the tail
 * keeps the e_i >= t, e_i > 0, for the threshold t the twin finds by sorting:
 *   t = max(t_tol, t_cap), t_tol = the largest tail value v with S(v) <= tol^2 E,
 *   t_cap = the cap-th largest tail value (cap = budget - head count), where
 *   S(v) = sum of the tail e < v and C(v) = #{tail e >= v};
 * t = +inf (no tail kept) when the whole tail is droppable or cap <= 0.
 * Non-negative floats order as their bit patterns (uint), so t is the largest bit
 * pattern u with P(u) = S(u) <= tol^2 E or C(u) >= cap (both parts hold for small u,
 * so P is true then false): a bisection on u, whose interval [lo, hi) is also
 * tightened to the tail values inside it (P only changes just above a value), so it
 * ends when one distinct value is left, in about log2(n) passes rather than 31.
 * Sums are float32 in 8 lanes (the twin sums sorted, sequentially): a
 * coefficient whose energy sits within rounding of the tolerance may go either way.
 *
 * select_threshold, work-item r = row r (its passes over the row run 8 entries at a
 * time, which a CPU vectorises; the row stays in cache): writes energy (R, n)
 * (scratch for select_write), the threshold bits, count and residual
 * sqrt(dropped / E) of each row.
 * select_write, work-item r = row r: the kept entries in depth-first order
 * (order[p] = the coefficient at depth-first position p), at the row's offset:
 * index (nnz,) ushort and value (nnz, CHANNELS) float. */
#pragma OPENCL FP_CONTRACT OFF

#define INF_BITS 0x7f800000u

/* Over the tail entries e[from .. n): S = sum of e < mid, C = #{e >= mid}, and the
 * smallest / largest bit pattern in [lo, mid) and in [mid, hi) (UINT_MAX / 0 if none). */
typedef struct { float s; int c; uint lo_min, lo_max, hi_min, hi_max; } pass_t;

inline pass_t bisection_pass(__global const float* e, int from, int n, uint lo, uint mid,
                             uint hi) {
    float8 s8 = (float8)(0.0f);
    int8 c8 = (int8)(0);
    uint8 lmin = (uint8)(UINT_MAX), lmax = (uint8)(0u), hmin = lmin, hmax = lmax;
    int i = from;
    for (; i + 8 <= n; i += 8) {
        float8 v = vload8(0, e + i);
        uint8 b = as_uint8(v);
        int8 below = b < (uint8)(mid);  /* -1 where true */
        s8 += select((float8)(0.0f), v, below);
        c8 -= ~below;                    /* +1 where b >= mid */
        int8 in_lo = below & (b >= (uint8)(lo)), in_hi = ~below & (b < (uint8)(hi));
        lmin = min(lmin, select((uint8)(UINT_MAX), b, in_lo));
        lmax = max(lmax, select((uint8)(0u), b, in_lo));
        hmin = min(hmin, select((uint8)(UINT_MAX), b, in_hi));
        hmax = max(hmax, select((uint8)(0u), b, in_hi));
    }
    pass_t p;
    float4 s4 = s8.lo + s8.hi;
    float2 s2 = s4.lo + s4.hi;
    p.s = s2.x + s2.y;
    int4 c4 = c8.lo + c8.hi;
    p.c = c4.x + c4.y + c4.z + c4.w;
    uint4 a = min(lmin.lo, lmin.hi), b4 = max(lmax.lo, lmax.hi),
          c = min(hmin.lo, hmin.hi), d = max(hmax.lo, hmax.hi);
    p.lo_min = min(min(a.x, a.y), min(a.z, a.w));
    p.lo_max = max(max(b4.x, b4.y), max(b4.z, b4.w));
    p.hi_min = min(min(c.x, c.y), min(c.z, c.w));
    p.hi_max = max(max(d.x, d.y), max(d.z, d.w));
    for (; i < n; ++i) {
        float v = e[i];
        uint b = as_uint(v);
        if (b < mid) {
            p.s += v;
            if (b >= lo) { p.lo_min = min(p.lo_min, b); p.lo_max = max(p.lo_max, b); }
        } else {
            p.c += 1;
            if (b < hi) { p.hi_min = min(p.hi_min, b); p.hi_max = max(p.hi_max, b); }
        }
    }
    return p;
}

__kernel void select_threshold(__global const float* coeffs,   /* (rows, CHANNELS, n) */
                               __global const float* weight,   /* CHANNELS */
                               const int first_row, const int rows, const int n,
                               const int keep_first, const int budget,
                               const float tolerance2,
                               __global float* energy,         /* (R, n) out */
                               __global uint* threshold,       /* (R,) bits */
                               __global int* count,            /* (R,) */
                               __global float* residual)       /* (R,) */
{
    int r = get_global_id(0);
    if (r >= rows) return;
    __global const float* c = coeffs + (size_t)(first_row + r) * CHANNELS * n;
    __global float* e = energy + (size_t)r * n;
    float head_sum = 0.0f;
    int head = 0;
    for (int i = 0; i < n; ++i) {
        float v = 0.0f;
        for (int ch = 0; ch < CHANNELS; ++ch) {
            float x = c[ch * n + i];
            float sq = x * x;
            v = v + weight[ch] * sq;
        }
        e[i] = v;
        if (i < keep_first) {
            head_sum += v;
            head += v > 0.0f;
        }
    }
    /* the whole tail: S(+inf) */
    float tail = bisection_pass(e, keep_first, n, 0u, INF_BITS, INF_BITS).s;
    float total = head_sum + tail, limit = tolerance2 * total;
    int cap = budget - head;
    bool none = tail <= limit || cap <= 0;  /* P(+inf) */
    uint lo = none ? INF_BITS : 0u, hi = INF_BITS;
    float dropped = tail;
    if (!none) {
        while (hi - lo > 1u) {
            uint mid = lo + (hi - lo) / 2u;
            pass_t p = bisection_pass(e, keep_first, n, lo, mid, hi);
            if (p.s <= limit || p.c >= cap) {   /* P(mid): t in [mid, hi) */
                if (p.hi_min == UINT_MAX) {     /* no value in [mid, hi) */
                    lo = mid;
                    break;
                }
                lo = p.hi_min;                  /* P is constant up to the next value */
                hi = p.hi_max + 1u;
            } else {                            /* t in [lo, mid) */
                hi = p.lo_min == UINT_MAX ? mid : p.lo_max + 1u;
                if (p.lo_min != UINT_MAX) lo = p.lo_min;
            }
        }
        pass_t p = bisection_pass(e, keep_first, n, 0u, lo, INF_BITS);
        dropped = p.s;
        for (int i = keep_first; i < n; ++i) head += e[i] > 0.0f && as_uint(e[i]) >= lo;
    }
    threshold[r] = lo;
    count[r] = head;
    residual[r] = total > 0.0f ? sqrt(dropped / total) : 0.0f;
}

__kernel void select_write(__global const float* coeffs,     /* (rows, CHANNELS, n) */
                           const int first_row, const int rows, const int n,
                           const int keep_first,
                           __global const float* energy,     /* (R, n) */
                           __global const uint* threshold,   /* (R,) */
                           __global const uint* offset,      /* (R,) first entry of each row */
                           __global const int* order,        /* (n,) depth-first order */
                           __global ushort* index,           /* (nnz,) out */
                           __global float* value)            /* (nnz, CHANNELS) out */
{
    int r = get_global_id(0);
    if (r >= rows) return;
    __global const float* c = coeffs + (size_t)(first_row + r) * CHANNELS * n;
    __global const float* e = energy + (size_t)r * n;
    uint t = threshold[r];
    size_t at = offset[r];
    for (int p = 0; p < n; ++p) {
        int i = order[p];
        float v = e[i];
        if (v > 0.0f && (i < keep_first || as_uint(v) >= t)) {
            index[at] = (ushort)i;
            for (int ch = 0; ch < CHANNELS; ++ch)
                value[at * CHANNELS + ch] = c[ch * n + i];
            ++at;
        }
    }
}

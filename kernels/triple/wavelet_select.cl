/* The stored rows of many coefficient rows at once: the OpenCL twin of
 * pipeline/methods/triple/wavelet_rows.py select_rows (the rule in its docstring), for method
 * triple's lighting and BRDF tables (launchers: pipeline/methods/triple/wavelet_select_cl.py).
 *
 * Row r (of rows first_row .. first_row + R - 1 of coeffs, laid out (rows, CHANNELS, n))
 * has energies e_i = sum_c w_c c_ic^2 (float32, channel by channel, no FMA: the
 * NumPy twin's rounding), total E. The head i < keep_first keeps every e_i > 0; the tail
 * keeps the e_i >= t, e_i > 0, for the threshold t the twin finds by sorting:
 *   t = max(t_tol, t_cap), t_tol = the largest tail value v with S(v) <= tol^2 E,
 *   t_cap = the cap-th largest tail value (cap = budget - head count), where
 *   S(v) = sum of the tail e < v and C(v) = #{tail e >= v};
 * t = +inf (no tail kept) when the whole tail is droppable or cap <= 0. The tail keeps
 * every e > t and, of the e = t, the first in depth-first order while the tail holds
 * fewer than cap (ties never take a row past its budget; an e = +inf, a map beyond
 * float32's range, is kept only below a finite t, so no row writes more than count).
 * Non-negative floats order as their bit patterns (uint), so t is the largest bit
 * pattern u with P(u) = S(u) <= tol^2 E or C(u) >= cap (both parts hold for small u,
 * so P is true then false): a radix select on u, 8 bits at a time from the top
 * (radix_threshold: 4 passes, each a 256-bin histogram of count and sum, the last two
 * over the entries the first two left in range only, instead of the ~14 passes of a
 * bisection, measured 3.9x less CPU on the BRDF table, then 1.43x less again).
 * Sums are float32 (per bin, then over bins; the twin sums sorted, sequentially): a
 * coefficient whose energy sits within rounding of the tolerance may go either way.
 *
 * select_threshold, work-item r = row r (the row stays in cache): writes energy (R, n)
 * (scratch for select_write), the threshold bits, the ties at it to keep, count and
 * residual sqrt(dropped / E) of each row; candidates (R, n) is radix_threshold's scratch.
 * select_write, work-item r = row r: the kept entries in depth-first order
 * (order[p] = the coefficient at depth-first position p), at the row's offset:
 * index (nnz,) ushort and value (nnz, CHANNELS) float; built with HALF, the values as
 * stored instead (pipeline/methods/triple/wavelet_rows.py to_half, the same float32 division and
 * round-to-nearest-even): value / scale as half, and scale (R,) = the row's largest
 * kept |value| (1 if none). */
#include "vectorize.h"

#pragma OPENCL FP_CONTRACT OFF

#define INF_BITS 0x7f800000u

/* The sum of e[from .. n), in 8 float32 lanes. */
inline float tail_sum(__global const float* e, int from, int n) {
    float8 s8 = (float8)(0.0f);
    int i = from;
    for (; i + 8 <= n; i += 8) s8 += vload8(0, e + i);
    float4 s4 = s8.lo + s8.hi;
    float2 s2 = s4.lo + s4.hi;
    float s = s2.x + s2.y;
    for (; i < n; ++i) s += e[i];
    return s;
}

/* Histogram (count, sum) by digit (b >> shift) & (bins - 1) of the entries v of
 * src[from .. n) whose bits b match prefix under mask; with compact != 0, those entries
 * are also copied, in order, to out[0 ..) (their number is returned). */
inline int digit_histogram(__global const float* src, int from, int n, uint mask,
                           uint prefix, int shift, uint bins, int* count, float* sum,
                           int compact, __global float* out) {
    for (uint d = 0; d < bins; ++d) {
        count[d] = 0;
        sum[d] = 0.0f;
    }
    int in_range = 0;
    for (int i = from; i < n; ++i) {
        float v = src[i];
        uint b = as_uint(v);
        if ((b & mask) == prefix) {
            uint d = (b >> shift) & (bins - 1u);
            count[d] += 1;
            sum[d] += v;
            if (compact) out[in_range] = v;
            in_range += 1;
        }
    }
    return in_range;
}

/* The threshold t (a bit pattern) of the tail e[from .. n) when P(+inf) is false: the
 * largest u with P(u) = S(u) <= limit or C(u) >= cap, found digit by digit, most
 * significant first (a radix select: bits 30..23, 22..15, 14..7, 6..0). Each pass
 * histograms (count, sum) the entries whose higher bits equal the prefix found so far
 * by their next digit d; with S_below = the sum of the entries under the prefix's
 * range and C_above = the count of those above it, P at the digit's lower edge is
 * S_below + sum of bins < d <= limit or C_above + count of bins >= d >= cap, true for
 * d = 0 (the range's lower edge, where P held), so the digit is the last d where it
 * holds. After the last digit t is the largest such pattern, *dropped = S(t) and
 * *kept = C_above = the tail entries with bits > t and *equal_to_t = those equal to t
 * (0 for t = 0: e = 0 is never kept). Four passes instead of a bisection's ~14; the second copies its range
 * (the entries of the first digit: one binade) to cand, in order, and the last two
 * read only those (measured 1.43x less CPU for the BRDF table's 8192 rows, the same
 * thresholds, counts and residuals). */
inline uint radix_threshold(__global const float* e, int from, int n, float limit, int cap,
                            __global float* cand, float* dropped, int* kept,
                            int* equal_to_t) {
    uint prefix = 0u, mask = 0u;
    float s_below = 0.0f;
    int c_above = 0, equal = 0, candidates = 0;
    for (int pass = 0; pass < 4; ++pass) {
        int shift = pass < 3 ? 23 - 8 * pass : 0;
        uint bins = pass < 3 ? 256u : 128u;
        int count[256];
        float sum[256];
        int in_range = pass < 2
            ? digit_histogram(e, from, n, mask, prefix, shift, bins, count, sum, pass == 1, cand)
            : digit_histogram(cand, 0, candidates, mask, prefix, shift, bins, count, sum, 0, cand);
        if (pass == 1) candidates = in_range;
        /* the last digit d where P holds at its lower edge */
        float s = s_below;
        int below = 0;
        uint digit = 0u;
        for (uint d = 0; d < bins; ++d) {
            if (!(s <= limit || c_above + in_range - below >= cap)) break;
            digit = d;
            s += sum[d];
            below += count[d];
        }
        for (uint d = 0; d < digit; ++d) s_below += sum[d];
        for (uint d = digit + 1u; d < bins; ++d) c_above += count[d];
        prefix |= digit << shift;
        mask |= (bins - 1u) << shift;
        equal = count[digit];
    }
    *dropped = s_below;
    *equal_to_t = prefix != 0u ? equal : 0;  /* e = 0 (bits 0) is never kept */
    *kept = c_above;
    return prefix;
}

PRT_SCALAR_ITEMS
__kernel void select_threshold(__global const float* coeffs,   /* (rows, CHANNELS, n) */
                               __global const float* weight,   /* CHANNELS */
                               const int first_row, const int rows, const int n,
                               const int keep_first, const int budget,
                               const float tolerance2,
                               __global float* energy,         /* (R, n) out */
                               __global float* candidates,     /* (R, n) scratch */
                               __global uint* threshold,       /* (R,) bits */
                               __global int* ties,             /* (R,) of e = t, kept */
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
        v = isnan(v) ? INFINITY : v;  /* counted and kept alike (bits > every finite t) */
        e[i] = v;
        if (i < keep_first) {
            head_sum += v;
            head += v > 0.0f;
        }
    }
    /* the whole tail: S(+inf) */
    float tail = tail_sum(e, keep_first, n);
    float total = head_sum + tail, limit = tolerance2 * total;
    int cap = budget - head;
    bool none = tail <= limit || cap <= 0;  /* P(+inf) */
    uint t = INF_BITS;
    float dropped = tail;
    int tied = 0;
    if (!none) {
        int above, equal;
        t = radix_threshold(e, keep_first, n, limit, cap, candidates + (size_t)r * n,
                            &dropped, &above, &equal);
        tied = min(equal, cap - above);  /* above < cap: P fails just past t */
        dropped += (float)(equal - tied) * as_float(t);
        head += above + tied;
    }
    threshold[r] = t;
    ties[r] = tied;
    count[r] = head;
    residual[r] = total > 0.0f ? sqrt(dropped / total) : 0.0f;
}

/* Whether entry i (energy v) is kept, visited in depth-first order; *tied counts down
 * the ties at t still to keep. */
inline bool kept_entry(int i, float v, int keep_first, uint t, int* tied) {
    if (!(v > 0.0f)) return false;  /* zero or NaN */
    if (i < keep_first || as_uint(v) > t) return true;
    if (as_uint(v) != t || *tied <= 0) return false;
    *tied -= 1;
    return true;
}

PRT_SCALAR_ITEMS
__kernel void select_write(__global const float* coeffs,     /* (rows, CHANNELS, n) */
                           const int first_row, const int rows, const int n,
                           const int keep_first,
                           __global const float* energy,     /* (R, n) */
                           __global const uint* threshold,   /* (R,) */
                           __global const int* ties,         /* (R,) */
                           __global const uint* offset,      /* (R,) first entry of each row */
                           __global const int* order,        /* (n,) depth-first order */
                           __global ushort* index,           /* (nnz,) out */
#ifdef HALF
                           __global half* value,             /* (nnz, CHANNELS) out */
                           __global float* scale)            /* (R,) out */
#else
                           __global float* value)            /* (nnz, CHANNELS) out */
#endif
{
    int r = get_global_id(0);
    if (r >= rows) return;
    __global const float* c = coeffs + (size_t)(first_row + r) * CHANNELS * n;
    __global const float* e = energy + (size_t)r * n;
    uint t = threshold[r];
    size_t at = offset[r];
#ifdef HALF
    /* the row's scale: its largest kept |value| (1 for a row with none or only zeros) */
    float peak = 0.0f;
    int tied = ties[r];
    for (int p = 0; p < n; ++p) {
        int i = order[p];
        if (kept_entry(i, e[i], keep_first, t, &tied))
            for (int ch = 0; ch < CHANNELS; ++ch) peak = fmax(peak, fabs(c[ch * n + i]));
    }
    float row_scale = peak > 0.0f ? peak : 1.0f;
    scale[r] = row_scale;
#endif
    int ties_left = ties[r];
    for (int p = 0; p < n; ++p) {
        int i = order[p];
        if (kept_entry(i, e[i], keep_first, t, &ties_left)) {
            index[at] = (ushort)i;
            for (int ch = 0; ch < CHANNELS; ++ch)
#ifdef HALF
                vstore_half_rte(c[ch * n + i] / row_scale, at * CHANNELS + ch, value);
#else
                value[at * CHANNELS + ch] = c[ch * n + i];
#endif
            ++at;
        }
    }
}

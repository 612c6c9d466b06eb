/* Sparse triple products of spherical Haar wavelets on the geodesic sphere: the OpenCL
 * twin of pipeline/math/sphwavelet.py (sparse_triple_product; read its docstring for the
 * basis, the layout and the tree sum).
 *
 * Each of the three functions is a weighted sum of up to SW_ROWS rows of a sparse
 * table (CSR: row r holds entries start[r] .. start[r + 1] - 1, each a coefficient
 * index (ushort, sorted depth first) and a value of 1 or 3 channels): bilinear or
 * trilinear interpolation between stored functions is that weighted sum, formed on the
 * fly while the rows are merged. Weights are RGB (float3), values grey (1 channel,
 * the same in R, G and B) or RGB, so a function may also be a per-channel mix of rows
 * (kd · diffuse row + ρs · glossy rows), and the triple product is taken per channel. The walk visits each triangle any row touches once, in depth-first order,
 * and keeps per function the path's coarse values f̄ and coefficients (depth ≤
 * SW_LEVELS): time linear in the entries read.
 *
 * Built with -D SW_LEVELS=L (the leaf level; N = 20·4^L ≤ 65536 so indices fit a
 * ushort). Basis tables (pipeline.math.sphwavelet.kernel_tables):
 *   root_area  20 floats: the roots' solid angles (sr)
 *   wavelet    12 floats per triangle of levels 0 .. L-1 (w[t][c]), triangle n of
 *              level l at (20·(4^l − 1)/3 + n)
 *   tensor     27 floats per triangle, T[a][b][c] = Σ_c a_c w_a w_b w_c */
#ifndef PRT_SPHWAVELET_H
#define PRT_SPHWAVELET_H

#include "inline.h"

#ifndef SW_LEVELS
#error "sphwavelet.h: build with -D SW_LEVELS=<leaf level>"
#endif
#ifndef SW_ROWS
#define SW_ROWS 8
#endif
#define SW_ROOTS 20
#define SW_END 0xffffffffu

/* First index of the wavelets of level l: 20·4^l. */
inline uint sw_level_start(uint l) { return (uint)SW_ROOTS << (2 * l); }

/* First triangle of level l in the wavelet and tensor tables: 20·(4^l − 1)/3. */
inline uint sw_node_base(uint l) { return (uint)SW_ROOTS * ((1u << (2 * l)) - 1u) / 3u; }

/* Level of a wavelet index (≥ 20): index ∈ [20·4^l, 20·4^(l+1)). */
inline uint sw_level(uint index) { return (31u - clz(index / SW_ROOTS)) / 2u; }

/* The depth-first sort key of a coefficient index (pipeline.math.sphwavelet.depth_first_keys). */
inline uint sw_key(uint index) {
    const uint shift = 2u * (SW_LEVELS - 1u);
    if (index < SW_ROOTS) return (index << shift) << 6;
    uint l = sw_level(index);
    uint rel = index - sw_level_start(l);
    uint node = rel / 3u;
    return ((((node << (shift - 2u * l)) << 4) | (l + 1u)) << 2) | (rel % 3u + 1u);
}

/* One function: a weighted sum of `count` rows of a CSR table being merged. */
typedef struct {
    __global const ushort* index;
    __global const float* value;
    uint head[SW_ROWS];
    uint end[SW_ROWS];
    float3 weight[SW_ROWS];
    int count;
    int channels;  /* values per entry: 1 (grey) or 3 (RGB) */
} sw_source;

/* *s made a source over rows[0 .. count-1] of the table (start, index, value with
 * `channels` values per entry) with RGB weights. (Filled through the pointer, not
 * returned: a struct returned by value, inlined, leaves LLVM noalias-scope intrinsics
 * that Oclgrind cannot run.) */
inline void sw_open(sw_source* s, __global const uint* start,
                        __global const ushort* index, __global const float* value,
                        int channels, const uint* rows, const float3* weight, int count) {
    s->index = index;
    s->value = value;
    s->count = count;
    s->channels = channels;
    for (int r = 0; r < count; ++r) {
        s->head[r] = start[rows[r]];
        s->end[r] = start[rows[r] + 1];
        s->weight[r] = weight[r];
    }
}

/* Lowers (*key, *index) to the smallest key at the heads of the source's rows. */
inline void sw_peek(const sw_source* s, uint* key, uint* index) {
    for (int r = 0; r < s->count; ++r) {
        if (s->head[r] >= s->end[r]) continue;
        uint i = s->index[s->head[r]];
        uint k = sw_key(i);
        if (k < *key) {
            *key = k;
            *index = i;
        }
    }
}

/* Takes the entries with indices in [first, first + n) from every row, summing
 * weight × value into c[index − first]. */
inline void sw_take(sw_source* s, uint first, uint n, float3* c) {
    for (uint k = 0; k < n; ++k) c[k] = (float3)(0.0f);
    for (int r = 0; r < s->count; ++r) {
        while (s->head[r] < s->end[r]) {
            uint e = s->head[r];
            uint i = s->index[e];
            if (i < first || i >= first + n) break;
            float3 v = s->channels == 3 ? vload3(e, s->value) : (float3)(s->value[e]);
            c[i - first] += s->weight[r] * v;
            ++s->head[r];
        }
    }
}

/* ∫ f g h dω per channel for the three sources (see the header comment). */
PRT_INLINE float3 sw_triple(sw_source* src, __global const float* root_area,
                        __global const float* wavelet, __global const float* tensor) {
    int path[SW_LEVELS];
    float3 own[3][SW_LEVELS][3];
    float3 coarse[3][SW_LEVELS];
    float3 total = (float3)(0.0f);
    for (int k = 0; k < SW_LEVELS; ++k) path[k] = -1;
    for (;;) {
        uint key = SW_END, index = 0;
        for (int f = 0; f < 3; ++f) sw_peek(&src[f], &key, &index);
        if (key == SW_END) return total;
        if (index < SW_ROOTS) {  /* a root's scaling coefficients open its subtree */
            float inv = rsqrt(root_area[index]);
            float3 prod = (float3)(root_area[index]);
            for (int f = 0; f < 3; ++f) {
                float3 s;
                sw_take(&src[f], index, 1u, &s);
                coarse[f][0] = s * inv;
                prod *= coarse[f][0];
                for (int t = 0; t < 3; ++t) own[f][0][t] = (float3)(0.0f);
            }
            path[0] = (int)index;
            for (int k = 1; k < SW_LEVELS; ++k) path[k] = -1;
            total += prod;
            continue;
        }
        uint level = sw_level(index);
        uint first = index - (index - sw_level_start(level)) % 3u;
        int node = (int)((first - sw_level_start(level)) / 3u);
        float3 c[3][3];
        for (int f = 0; f < 3; ++f) sw_take(&src[f], first, 3u, c[f]);
        for (uint k = 0; k <= level; ++k) {  /* bring the path down to this triangle */
            int ancestor = node >> (2 * (level - k));
            if (path[k] == ancestor && k < level) continue;
            if (k == 0 && path[0] != ancestor) {
                for (int f = 0; f < 3; ++f) coarse[f][0] = (float3)(0.0f);
            } else if (k > 0) {
                __global const float* w = wavelet + 12 * (sw_node_base(k - 1) + path[k - 1]);
                int slot = ancestor & 3;
                for (int f = 0; f < 3; ++f)
                    coarse[f][k] = coarse[f][k - 1] + own[f][k - 1][0] * w[slot]
                                 + own[f][k - 1][1] * w[4 + slot] + own[f][k - 1][2] * w[8 + slot];
            }
            path[k] = ancestor;
            for (int f = 0; f < 3; ++f)
                for (int t = 0; t < 3; ++t) own[f][k][t] = (float3)(0.0f);
        }
        for (int f = 0; f < 3; ++f)
            for (int t = 0; t < 3; ++t) own[f][level][t] = c[f][t];
        float3 fg = (float3)(0.0f), fh = (float3)(0.0f), gh = (float3)(0.0f);
        for (int t = 0; t < 3; ++t) {
            fg += c[0][t] * c[1][t];
            fh += c[0][t] * c[2][t];
            gh += c[1][t] * c[2][t];
        }
        total += fg * coarse[2][level] + fh * coarse[1][level] + gh * coarse[0][level];
        __global const float* T = tensor + 27 * (sw_node_base(level) + node);
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
                float3 ab = c[0][a] * c[1][b];
                total += ab * (T[9 * a + 3 * b] * c[2][0] + T[9 * a + 3 * b + 1] * c[2][1]
                               + T[9 * a + 3 * b + 2] * c[2][2]);
            }
    }
}

#endif

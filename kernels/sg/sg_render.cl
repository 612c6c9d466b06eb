/* Method sg's frame (pipeline/methods/sg/render.py; NumPy twins view_triangles, shade_numpy).
 * One work-item per pixel that sees a surface (or, for sg_background, misses).
 *
 * sg_view_lookup: the view triangle containing the pixel's direction to the eye w_o
 * (world, unit) among the 180 geodesic triangles of the 92 views, searched in two
 * levels: the icosahedron face (20) whose cone holds w_o, then its 9 sub-triangles.
 * A triangle (a, b, c) stores the inverse M^-1 of M = [a b c] (columns): the weights
 * beta = M^-1 w_o are all >= 0 exactly when w_o lies in the triangle's cone, and
 * beta / sum(beta) are its gnomonic barycentrics (exact at the views, continuous across
 * edges). The triangle whose smallest weight is largest is taken (no branch on a
 * threshold: a w_o on an edge picks either side, both give the same weights);
 * rounding's tiny negatives are clamped to 0 before normalising.
 *
 * sg_shade: per lobe slot s < the largest count of the face's 3 vertices, the lobe
 * blended over 3 vertices x 3 views with weights W = face barycentric x view weight:
 *     w = sum W w_i,  mu = normalise(sum W mu_i),
 *     lam = exp(sum W log lam_i)   (LAMBDA_LOG = 1: linear in log sigma; the host
 *                                   stores log lam in the lobes' last field)
 *         | sum W lam_i            (LAMBDA_LOG = 0),
 * where, with PIXEL_NORMAL = 1 (decision 0039), mu_i is vertex a's stored mean turned
 * towards the pixel's normal: about the axis t_a = r_a x r_p / |r_a x r_p| that takes
 * the vertex's mirror direction r_a = reflect(w_o, n_a) to the pixel's r_p =
 * reflect(w_o, n_p) (n_p = normalise(sum_a f_a n_a), the normal the path tracer shades
 * with), by the angle G(r_a; mu_i, lam_i) * angle(r_a, r_p): a lobe about the mirror
 * direction (the BRDF's highlight) turns all the way and the highlight follows the
 * pixel's normal across the face; a lobe away from it (shaped by occlusion, or the
 * indirect light) keeps its place, since its light does not follow the normal (a full
 * turn of every lobe measured worse than none: decision 0039). No turn where
 * |r_a x r_p| <= 1e-6 or n_p is undefined. w_o per pixel (P x 3), n per vertex (V x 3).
 * With BRDF_RATIO = 1 (decision 0042) the lobes are not turned: each vertex's lobes are
 * blended over its 3 views alone and integrated, F_a; with F = sum_a f_a F_a and
 * U = sum_a f_a U_a the glossy light is, per channel,
 *     F + v (U_p - U),   v = min(1, F / U)
 * (= U_p F / U where the vertices hold less than the unshadowed light, a visibility
 * ratio; F + U_p - U where they hold more, indirect light: no ratio blows up where the
 * vertices' BRDF lobes miss a source the pixel's sees), U the radiance of the face's
 * BRDF lobe under the map alone (no visibility): one Gaussian per view elevation
 * c = n.w_o from the material's table (lobe_table, rows of SG_LOBE_TABLE x (theta, lam,
 * a), pipeline/methods/sg/brdf_lobe.py; vertex_lobe: each vertex's row block, -1 none),
 * U_p at the pixel's normal n_p, U_a at the vertex's. The vertices keep the visibility
 * and the indirect light, the pixel's normal places the highlight. F alone where a
 * corner has no table or another than corner 0's, or where n_p is undefined or
 * n_p.w_o <= 0; v = 1 where U <= 1e-6 U_p.
 * The lobe is integrated against the environment by the prefiltered stack at R^T mu (sg.h's
 * sg_env_integral); plus the diffuse SH term sum_k (sum_v bary_v transfer[v, c, k])
 * L[k, c] = sum_v bary_v D[v, c], D[v, c] = sum_k transfer[v, c, k] L[k, c] computed
 * per frame on the host (the sum is linear); all times the light's scale. Lobes: the
 * stored slots, R x VIEWS x 7 floats (w_rgb, mu_xyz, lam), vertex v's in rows
 * first[v] .. first[v + 1] - 1 (first: V + 1 ints); D V x 3 floats. */
#include "inline.h"
#include "sg.h"
#include "brdf.h"

#ifndef LAMBDA_LOG
#define LAMBDA_LOG 1
#endif
#ifndef PIXEL_NORMAL
#define PIXEL_NORMAL 0
#endif
#ifndef BRDF_RATIO
#define BRDF_RATIO 0
#endif
#ifndef SG_LOBE_TABLE
#define SG_LOBE_TABLE 32
#endif
#define SG_FIELDS 7

/* beta = M^-1 d for the 3x3 row-major inverse at m. */
PRT_INLINE float3 sg_cone_weights(__global const float* m, float3 d) {
    return (float3)(m[0] * d.x + m[1] * d.y + m[2] * d.z,
                    m[3] * d.x + m[4] * d.y + m[5] * d.z,
                    m[6] * d.x + m[7] * d.y + m[8] * d.z);
}

PRT_INLINE float sg_min3(float3 b) { return fmin(b.x, fmin(b.y, b.z)); }

/* The mirror direction of w about unit n: 2 (w.n) n - w. */
PRT_INLINE float3 sg_reflect(float3 w, float3 n) { return 2.0f * dot(w, n) * n - w; }

/* v turned by angle about the unit axis t (Rodrigues). */
PRT_INLINE float3 sg_turn(float3 t, float angle, float3 v) {
    float c = cos(angle), s = sin(angle);
    return c * v + s * cross(t, v) + (1.0f - c) * dot(t, v) * t;
}

/* The BRDF lobe of a material's table (SG_LOBE_TABLE rows of theta, lam, a; linear in
 * c = n.d between rows) at unit normal n and eye direction d: the mean (cos theta n -
 * sin theta t, t the unit part of d along the surface) and sharpness; returns a, 0 where
 * n.d <= 0 (brdf_lobe.py's brdf_lobe). */
PRT_INLINE float sg_brdf_lobe(__global const float* table, float3 n, float3 d, float3* mu,
                              float* lam) {
    float c = dot(n, d);
    float x = clamp(c, 0.0f, 1.0f) * (float)(SG_LOBE_TABLE - 1);
    int k = min((int)floor(x), SG_LOBE_TABLE - 2);
    float t = x - (float)k;
    __global const float* r = table + 3 * k;
    float theta = (1.0f - t) * r[0] + t * r[3];
    *lam = (1.0f - t) * r[1] + t * r[4];
    float a = (1.0f - t) * r[2] + t * r[5];
    float3 side = d - c * n;
    float len = length(side);
    side = len > 1e-6f ? side / len : (float3)(0.0f);
    *mu = normalize(cos(theta) * n - sin(theta) * side);
    return c > 0.0f ? a : 0.0f;
}

__kernel void sg_view_lookup(__global const float* parent_inverse,  /* 20 x 9 */
                             __global const int* children,          /* 20 x 9 */
                             __global const float* face_inverse,    /* 180 x 9 */
                             __global const int* face_views,        /* 180 x 3 */
                             __global const float* wo, const int n,
                             __global int* view_out, __global float* weight_out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float3 d = vload3(i, wo);
    int parent = 0;
    float best = -INFINITY;
    for (int p = 0; p < 20; ++p) {
        float m = sg_min3(sg_cone_weights(parent_inverse + 9 * p, d));
        if (m > best) { best = m; parent = p; }
    }
    int face = children[9 * parent];
    best = -INFINITY;
    for (int c = 0; c < 9; ++c) {
        int f = children[9 * parent + c];
        float m = sg_min3(sg_cone_weights(face_inverse + 9 * f, d));
        if (m > best) { best = m; face = f; }
    }
    float3 b = fmax(sg_cone_weights(face_inverse + 9 * face, d), (float3)(0.0f));
    b /= b.x + b.y + b.z;
    vstore3(b, i, weight_out);
    view_out[3 * i] = face_views[3 * face];
    view_out[3 * i + 1] = face_views[3 * face + 1];
    view_out[3 * i + 2] = face_views[3 * face + 2];
}

__kernel void sg_shade(__global const float* lobes, __global const int* first,
                       __global const uchar* count,
                       __global const float* vertex_diffuse, const int views,
                       __global const int* corner, __global const float* bary,
                       __global const int* view, __global const float* view_weight,
                       __global const float* normal, __global const float* wo,
                       __global const float* lobe_table, __global const int* vertex_lobe,
                       __global const float* stack, __global const int* level_info,
                       const int levels, const float log_sigma0, const float inv_log_ratio,
                       __global const float* map_turn,
                       const float scale, const int n,
                       __global float* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    int v[3] = {corner[3 * i], corner[3 * i + 1], corner[3 * i + 2]};
    float fb[3] = {bary[3 * i], bary[3 * i + 1], bary[3 * i + 2]};
    int j[3] = {view[3 * i], view[3 * i + 1], view[3 * i + 2]};
    float vb[3] = {view_weight[3 * i], view_weight[3 * i + 1], view_weight[3 * i + 2]};
    int base[3], stored[3];
    for (int a = 0; a < 3; ++a) {
        base[a] = first[v[a]];
        stored[a] = first[v[a] + 1] - base[a];
    }
    int slots = max((int)count[v[0]], max((int)count[v[1]], (int)count[v[2]]));
    float3 turn_t[3] = {(float3)(0.0f), (float3)(0.0f), (float3)(0.0f)};
    float3 turn_r[3] = {(float3)(0.0f), (float3)(0.0f), (float3)(0.0f)};
    float turn_angle[3] = {0.0f, 0.0f, 0.0f};
#if PIXEL_NORMAL
    if (slots > 0) {
        float3 n[3] = {vload3(v[0], normal), vload3(v[1], normal), vload3(v[2], normal)};
        float3 np = fb[0] * n[0] + fb[1] * n[1] + fb[2] * n[2];
        float len_np = length(np);
        if (len_np > 0.0f) {
            float3 d = vload3(i, wo);
            float3 rp = sg_reflect(d, np / len_np);
            for (int a = 0; a < 3; ++a) {
                float3 ra = sg_reflect(d, n[a]);
                float3 t = cross(ra, rp);
                float sine = length(t);
                if (sine > 1e-6f) {
                    turn_t[a] = t / sine;
                    turn_r[a] = ra;
                    turn_angle[a] = atan2(sine, dot(ra, rp));
                }
            }
        }
    }
#endif
    float3 radiance = (float3)(0.0f);
#if BRDF_RATIO
    for (int s = 0; s < slots; ++s) {
        for (int a = 0; a < 3; ++a) {
            if (stored[a] == 0) continue;
            int row = base[a] + (s < stored[a] ? s : 0);
            float keep = s < stored[a] ? 1.0f : 0.0f;
            float3 w = (float3)(0.0f), mu = (float3)(0.0f);
            float lam = 0.0f;
            for (int b = 0; b < 3; ++b) {
                __global const float* p = lobes + (row * views + j[b]) * SG_FIELDS;
                w += (vb[b] * keep) * (float3)(p[0], p[1], p[2]);
                mu += vb[b] * (float3)(p[3], p[4], p[5]);
                lam += vb[b] * p[6];
            }
#if LAMBDA_LOG
            lam = exp(lam);
#endif
            float len = length(mu);
            if (!(len > 0.0f)) continue;
            radiance += fb[a] * sg_env_integral(stack, level_info, levels, log_sigma0,
                                                inv_log_ratio,
                                                envmap_into_map(mu / len, map_turn), lam, w);
        }
    }
    int m = vertex_lobe[v[0]];
    if (slots > 0 && m >= 0 && vertex_lobe[v[1]] == m && vertex_lobe[v[2]] == m) {
        float3 n[3] = {vload3(v[0], normal), vload3(v[1], normal), vload3(v[2], normal)};
        float3 np = fb[0] * n[0] + fb[1] * n[1] + fb[2] * n[2];
        float len_np = length(np);
        float3 d = vload3(i, wo);
        if (len_np > 0.0f && dot(np, d) > 0.0f) {
            __global const float* table = lobe_table + 3 * SG_LOBE_TABLE * m;
            float3 mu;
            float lam;
            float a = sg_brdf_lobe(table, np / len_np, d, &mu, &lam);
            float3 up = sg_env_integral(stack, level_info, levels, log_sigma0, inv_log_ratio,
                                        envmap_into_map(mu, map_turn), lam, (float3)(a));
            float3 ua = (float3)(0.0f);
            for (int c = 0; c < 3; ++c) {
                a = sg_brdf_lobe(table, n[c], d, &mu, &lam);
                if (a > 0.0f)
                    ua += fb[c] * sg_env_integral(stack, level_info, levels, log_sigma0,
                                                  inv_log_ratio,
                                                  envmap_into_map(mu, map_turn), lam,
                                                  (float3)(a));
            }
            /* v = min(1, F / U_a-sum): the vertices' share of the unshadowed light */
            int3 ok = isgreater(ua, 1e-6f * up) && isgreater(ua, (float3)(0.0f));
            float3 v = select((float3)(1.0f), fmin(radiance / ua, (float3)(1.0f)), ok);
            radiance += v * (up - ua);
        }
    }
#else
    for (int s = 0; s < slots; ++s) {
        float3 w = (float3)(0.0f), mu = (float3)(0.0f);
        float lam = 0.0f;
        for (int a = 0; a < 3; ++a) {
            if (stored[a] == 0) continue;  /* no glossy part: adds nothing */
            /* a slot beyond the corner's stored ones: its slot 0's mean and sharpness,
               w = 0 (data_schema/sg/sg_lobes.yaml) */
            int row = base[a] + (s < stored[a] ? s : 0);
            float keep = s < stored[a] ? 1.0f : 0.0f;
            for (int b = 0; b < 3; ++b) {
                float weight = fb[a] * vb[b];
                __global const float* p = lobes + (row * views + j[b]) * SG_FIELDS;
                w += (weight * keep) * (float3)(p[0], p[1], p[2]);
                float3 m = (float3)(p[3], p[4], p[5]);
#if PIXEL_NORMAL
                if (turn_angle[a] > 0.0f) {
#if LAMBDA_LOG
                    float lam_ab = exp(p[6]);
#else
                    float lam_ab = p[6];
#endif
                    m = sg_turn(turn_t[a], sg_eval(turn_r[a], m, lam_ab) * turn_angle[a], m);
                }
#endif
                mu += weight * m;
                lam += weight * p[6];  /* log lam with LAMBDA_LOG */
            }
        }
#if LAMBDA_LOG
        lam = exp(lam);
#endif
        float len = length(mu);
        if (!(len > 0.0f)) continue;  /* opposite means cancel: no defined direction */
        float3 mu_map = envmap_into_map(mu / len, map_turn);
        radiance += sg_env_integral(stack, level_info, levels, log_sigma0, inv_log_ratio,
                                    mu_map, lam, w);
    }
#endif
    float3 diffuse = fb[0] * vload3(v[0], vertex_diffuse) + fb[1] * vload3(v[1], vertex_diffuse)
                   + fb[2] * vload3(v[2], vertex_diffuse);
    vstore3(scale * (radiance + diffuse), i, out);
}

/* sg_shade_visibility (decision 0046; pipeline/methods/sg/visibility.py, twin
 * visibility.glossy): no lobes. The BRDF x cosine at the pixel's normal n_p is held by
 * 7 Gaussians of sharpness SG_SPLIT lam about the mean mu of the material's one-Gaussian
 * lobe (sg_brdf_lobe): mu and a ring at SG_RING / sqrt(lam), the first towards n_p,
 * weights w_k from the material's node table (SG_LOBE_TABLE rows of 7, linear in
 * c = n_p.w_o). Per node the light L_k = w_k rho_s integral(G_k L) (the stack) and per
 * corner the visibility V_ak from the corner's octahedral pyramid (sg_visibility);
 * glossy = sum_a f_a [sum_k V_ak L_k + (1 - sum_k s_k V_ak) rho_s sum_k w_k
 * integral(G_k) O_a], s_k = w_k / sum w, O_a the corner's occluder radiance
 * (vertex_light: per vertex the diffuse radiance D (3) then O (3), per frame on the
 * host). No glossy light where the corners' table rows differ or are -1, or
 * n_p.w_o <= 0. Bright sources (decision 0048, sources.py): the stack is then the map's
 * less its source_count sources (world direction, power P_s, sharpness lam_s; 7 floats
 * each), and each adds rho_s f(w_s, w_o) max(0, n_p.w_s) K_s P_s sum_a f_a S_a,s, f
 * the material's glossy BRDF (kernels/brdf.h, row m of materials) in the frame
 * sg_basis(n_p), S_a,s = source_seen[a * source_count + s] what corner a sees of the
 * source this frame (per vertex on the host: render.source_seen, decision 0049), K_s
 * the source's spread through the lobe (mu, lam) (sources.py spread). */
#define SG_NODES 7
#define SG_RING 1.18f
#define SG_SPLIT 2.0f
#define SG_FILTER 1.0f
#define SG_SPREAD_CAP 2.0f  /* sources.py SPREAD_CAP */

/* t, s completing unit n to a right-handed frame (Duff et al. 2017; visibility.py's
 * orthonormal_basis). */
PRT_INLINE void sg_basis(float3 n, float3* t, float3* s) {
    float sign = n.z >= 0.0f ? 1.0f : -1.0f;
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    *t = (float3)(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    *s = (float3)(b, sign + n.y * n.y * a, -n.y);
}

/* Bilinear escape fraction of one pyramid level (size x size texels at offset) at
 * octahedral coordinates (u, v), texel indices clamped to the level. */
PRT_INLINE float sg_visibility_level(__global const uchar* map, int offset, int size,
                                     float u, float v) {
    float x = (u + 1.0f) * 0.5f * (float)size - 0.5f;
    float y = (v + 1.0f) * 0.5f * (float)size - 0.5f;
    float x0 = floor(x), y0 = floor(y);
    float fx = x - x0, fy = y - y0;
    int xi0 = clamp((int)x0, 0, size - 1), xi1 = clamp((int)x0 + 1, 0, size - 1);
    int yi0 = clamp((int)y0, 0, size - 1), yi1 = clamp((int)y0 + 1, 0, size - 1);
    __global const uchar* m = map + offset;
    float a = (1.0f - fx) * (float)m[yi0 * size + xi0] + fx * (float)m[yi0 * size + xi1];
    float b = (1.0f - fx) * (float)m[yi1 * size + xi0] + fx * (float)m[yi1 * size + xi1];
    return ((1.0f - fy) * a + fy * b) * (1.0f / 255.0f);
}

/* Visibility of one vertex's packed pyramid (resolution R, levels R .. 1) towards unit
 * d (world), filtered over sigma rad (visibility.py's lookup). */
PRT_INLINE float sg_visibility(__global const uchar* map, int resolution, int count,
                               float3 d, float sigma) {
    float level = log2(fmax(SG_FILTER * sigma * (float)resolution * 0.28209479f, 1e-30f));
    level = clamp(level, 0.0f, (float)(count - 1));
    int lo = min((int)floor(level), max(count - 2, 0));
    int hi = min(lo + 1, count - 1);
    float t = level - (float)lo;
    float3 p = d / (fabs(d.x) + fabs(d.y) + fabs(d.z));
    float u = p.x, v = p.y;
    if (p.z < 0.0f) {
        u = (1.0f - fabs(p.y)) * (p.x >= 0.0f ? 1.0f : -1.0f);
        v = (1.0f - fabs(p.x)) * (p.y >= 0.0f ? 1.0f : -1.0f);
    }
    int offset = 0, size = resolution;
    float value = 0.0f;
    for (int l = 0; l <= hi; ++l) {
        if (l == lo) value += (1.0f - t) * sg_visibility_level(map, offset, size, u, v);
        if (l == hi) value += t * sg_visibility_level(map, offset, size, u, v);
        offset += size * size;
        size = max(size / 2, 1);
    }
    return value;
}

__kernel void sg_shade_visibility(__global const uchar* maps, const int resolution,
                                  const int map_texels, const int map_levels,
                                  __global const float* vertex_light,
                                  __global const int* corner, __global const float* bary,
                                  __global const float* normal, __global const float* wo,
                                  __global const float* lobe_table,
                                  __global const float* node_table,
                                  __global const float* lobe_specular,
                                  __global const int* vertex_lobe,
                                  __global const float* stack, __global const int* level_info,
                                  const int levels, const float log_sigma0,
                                  const float inv_log_ratio, __global const float* map_turn,
                                  __global const float* sources, const int source_count,
                                  __global const float* source_seen,
                                  __global const float* materials,
                                  const float scale, const int n, __global float* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    int v[3] = {corner[3 * i], corner[3 * i + 1], corner[3 * i + 2]};
    float fb[3] = {bary[3 * i], bary[3 * i + 1], bary[3 * i + 2]};
    float3 radiance = (float3)(0.0f);
    int m = vertex_lobe[v[0]];
    float3 np = fb[0] * vload3(v[0], normal) + fb[1] * vload3(v[1], normal)
              + fb[2] * vload3(v[2], normal);
    float len_np = length(np);
    float3 d = vload3(i, wo);
    if (m >= 0 && vertex_lobe[v[1]] == m && vertex_lobe[v[2]] == m && len_np > 0.0f
        && dot(np, d) > 0.0f) {
        float3 np_unit = np / len_np;
        float3 mu;
        float lam;
        sg_brdf_lobe(lobe_table + 3 * SG_LOBE_TABLE * m, np_unit, d, &mu, &lam);
        float x = clamp(dot(np_unit, d), 0.0f, 1.0f) * (float)(SG_LOBE_TABLE - 1);
        int row = min((int)floor(x), SG_LOBE_TABLE - 2);
        float t_row = x - (float)row;
        __global const float* w0 = node_table + SG_NODES * (SG_LOBE_TABLE * m + row);
        float total = 0.0f;
        for (int k = 0; k < SG_NODES; ++k)
            total += (1.0f - t_row) * w0[k] + t_row * w0[k + SG_NODES];
        if (total > 0.0f) {
            float3 e1 = np_unit - dot(np_unit, mu) * mu;
            float len_e1 = length(e1);
            float3 e2 = (float3)(0.0f);
            if (len_e1 > 1e-6f) {
                e1 /= len_e1;
            } else {
                sg_basis(mu, &e1, &e2);
            }
            e2 = cross(mu, e1);
            float angle = SG_RING * rsqrt(lam);
            float lam_n = SG_SPLIT * lam;
            float sigma = rsqrt(lam_n);
            float3 specular = vload3(m, lobe_specular);
            float3 whole = specular * (total * sg_integral(lam_n));
            float seen[3] = {0.0f, 0.0f, 0.0f};
            for (int k = 0; k < SG_NODES; ++k) {
                float3 node = mu;
                if (k > 0) {
                    float phi = (float)(k - 1) * (SG_TWO_PI / 6.0f);
                    node = cos(angle) * mu + sin(angle) * (cos(phi) * e1 + sin(phi) * e2);
                }
                float w_k = (1.0f - t_row) * w0[k] + t_row * w0[k + SG_NODES];
                float3 light = sg_env_integral(stack, level_info, levels, log_sigma0,
                                               inv_log_ratio, envmap_into_map(node, map_turn),
                                               lam_n, w_k * specular);
                for (int c = 0; c < 3; ++c) {
                    float vis = sg_visibility(maps + (size_t)v[c] * map_texels, resolution,
                                              map_levels, node, sigma);
                    radiance += (fb[c] * vis) * light;
                    seen[c] += (w_k / total) * vis;
                }
            }
            for (int c = 0; c < 3; ++c)
                radiance += (fb[c] * (1.0f - seen[c])) * whole * vload3(2 * v[c] + 1, vertex_light);
            float3 t, s;
            sg_basis(np_unit, &t, &s);
            float3 lo = (float3)(dot(d, t), dot(d, s), dot(d, np_unit));
            for (int k = 0; k < source_count; ++k) {
                __global const float* src = sources + 7 * k;
                float3 ws = vload3(0, src);
                float cos_s = dot(np_unit, ws);
                if (cos_s <= 0.0f) continue;
                float3 li = (float3)(dot(ws, t), dot(ws, s), cos_s);
                float f = brdf_glossy(materials + MATERIAL_FLOATS * m, li, lo) * cos_s;
                float lam_s = src[6];
                float vis = fb[0] * source_seen[v[0] * source_count + k]
                          + fb[1] * source_seen[v[1] * source_count + k]
                          + fb[2] * source_seen[v[2] * source_count + k];
                float3 dd = mu - ws;  /* K_s, the source's spread through the lobe */
                float r = length(lam * mu + lam_s * ws);
                float log_k = 0.5f * lam * dot(dd, dd) * (1.0f - 2.0f * lam_s / (r + lam + lam_s))
                              + log(sg_integral(r) / sg_integral(lam_s));
                radiance += (f * exp(fmin(log_k, SG_SPREAD_CAP)) * vis) * specular
                            * vload3(1, src);
            }
        }
    }
    float3 diffuse = fb[0] * vload3(2 * v[0], vertex_light) + fb[1] * vload3(2 * v[1], vertex_light)
                   + fb[2] * vload3(2 * v[2], vertex_light);
    vstore3(scale * (radiance + diffuse), i, out);
}

/* Pixels that miss: the environment map itself, rotated, times the light's scale. */
__kernel void sg_background(__global const float* rgb, const int width, const int height,
                            __global const float* direction,
                            __global const float* map_turn, const float scale, const int n,
                            __global float* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float3 d = envmap_into_map(vload3(i, direction), map_turn);
    vstore3(scale * envmap_radiance(rgb, width, height, d), i, out);
}

/* Method triple's G-buffer surface attributes, one work-item per shaded pixel, from the
 * camera ray's first hit (face, barycentrics u, v of the face's vertices 1 and 2).
 * NumPy twin: pipeline.device.raytrace.Surface (normal, tangent) and Atlas.texel_xy, as
 * pipeline/methods/triple/render.py camera_gbuffer_numpy assembles them. All float32, world
 * frame; flat arrays of 3-vectors (x, y, z) and 2-vectors.
 *
 *   normal  = ±normalize(w·n0 + u·n1 + v·n2), w = 1 − u − v, the sign that turns the
 *             face's geometric normal against the ray (d · n_face ≤ 0);
 *   tangent = the face's unit dP/du made ⊥ normal (Gram–Schmidt), or where that fails
 *             (no uv on the face, or dP/du ∥ normal) Duff et al.'s tangent of the normal
 *             (pipeline/math/frames.py tangent_from_normal);
 *   view    = −d;  texel_xy = w·c0 + u·c1 + v·c2 of the face's atlas corners (texels);
 *   object  = the face's object;
 *   back    = 1 where the ray meets the back of its face (d · n_face > 0), else 0
 *             (pipeline/render/__init__.py sees_back). */

/* Written for PoCL's loop vectorizer (POCL_VECTORIZER_REMARKS=1 reports "vectorized
 * loop (vectorization width: 4)"): no early return, scalar loads, selects instead of
 * branches, and on PoCL clang's __builtin_sqrtf (PoCL's sqrt is an out-of-line call,
 * which stops the vectorizer; this is the same IEEE sqrt). 0.6× the CPU time of the
 * float3 version. The builtin is not OpenCL C (Oclgrind cannot run the LLVM intrinsic it
 * becomes), so elsewhere it is sqrt: pipeline/device/cl.py defines PRT_POCL on PoCL. */
#ifdef PRT_POCL
#define SURFACE_SQRT __builtin_sqrtf
#else
#define SURFACE_SQRT sqrt
#endif

/* Gram–Schmidt fails below this length of t − (t·n) n for a unit t (float32: 1e-6 is
 * ~10 ulp of 1; the host twin's 1e-8 is for a float64 t of any length). */
#define TANGENT_MIN_LENGTH 1e-6f

__kernel void triple_surface(__global const int* pixel, __global const int* prim,
                             __global const float* hit_u, __global const float* hit_v,
                             __global const float* direction, __global const int* faces,
                             __global const float* vertex_normal,
                             __global const float* face_normal,
                             __global const float* face_tangent,
                             __global const float* face_uv, __global const int* face_object,
                             const int n, __global float* normal, __global float* tangent,
                             __global float* view, __global float* texel_xy,
                             __global int* object, __global uchar* back)
{
    int g = get_global_id(0);
    int i = g < n ? g : n - 1;  /* the padding items redo the last pixel (no early return) */
    int p = pixel[i];
    int f = prim[p];
    float u = hit_u[p], v = hit_v[p];
    float w = 1.0f - u - v;
    float dx = direction[3 * p], dy = direction[3 * p + 1], dz = direction[3 * p + 2];
    int a = 3 * faces[3 * f], b = 3 * faces[3 * f + 1], c = 3 * faces[3 * f + 2];
    float nx = w * vertex_normal[a] + u * vertex_normal[b] + v * vertex_normal[c];
    float ny = w * vertex_normal[a + 1] + u * vertex_normal[b + 1] + v * vertex_normal[c + 1];
    float nz = w * vertex_normal[a + 2] + u * vertex_normal[b + 2] + v * vertex_normal[c + 2];
    float len = SURFACE_SQRT(nx * nx + ny * ny + nz * nz);
    int behind = (face_normal[3 * f] * dx + face_normal[3 * f + 1] * dy
                  + face_normal[3 * f + 2] * dz) > 0.0f;
    float s = behind ? -1.0f : 1.0f;
    float scale = s / (len > 1e-30f ? len : 1e-30f);
    nx *= scale; ny *= scale; nz *= scale;
    float fx = face_tangent[3 * f], fy = face_tangent[3 * f + 1], fz = face_tangent[3 * f + 2];
    float k = fx * nx + fy * ny + fz * nz;
    float tx = fx - k * nx, ty = fy - k * ny, tz = fz - k * nz;
    float tl = SURFACE_SQRT(tx * tx + ty * ty + tz * tz);
    int ok = tl > TANGENT_MIN_LENGTH;
    float inv = 1.0f / (ok ? tl : 1.0f);
    float sign = nz >= 0.0f ? 1.0f : -1.0f;
    float da = -1.0f / (sign + nz);
    float db = nx * ny * da;
    tx = ok ? tx * inv : 1.0f + sign * nx * nx * da;
    ty = ok ? ty * inv : sign * db;
    tz = ok ? tz * inv : -sign * nx;
    normal[3 * i] = nx; normal[3 * i + 1] = ny; normal[3 * i + 2] = nz;
    tangent[3 * i] = tx; tangent[3 * i + 1] = ty; tangent[3 * i + 2] = tz;
    view[3 * i] = -dx; view[3 * i + 1] = -dy; view[3 * i + 2] = -dz;
    texel_xy[2 * i] = w * face_uv[6 * f] + u * face_uv[6 * f + 2] + v * face_uv[6 * f + 4];
    texel_xy[2 * i + 1] = w * face_uv[6 * f + 1] + u * face_uv[6 * f + 3] + v * face_uv[6 * f + 5];
    object[i] = face_object[f];
    back[i] = (uchar)behind;
}

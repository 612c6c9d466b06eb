/* Method triple's G-buffer surface attributes, one work-item per shaded pixel, from the
 * camera ray's first hit (face, barycentrics u, v of the face's vertices 1 and 2).
 * NumPy twin: pipeline.raytrace.Surface (normal, tangent) and Atlas.texel_xy, as
 * pipeline/render/triple.py camera_gbuffer_numpy assembles them. All float32, world
 * frame; flat arrays of 3-vectors (x, y, z) and 2-vectors.
 *
 *   normal  = ±normalize(w·n0 + u·n1 + v·n2), w = 1 − u − v, the sign that turns the
 *             face's geometric normal against the ray (d · n_face ≤ 0);
 *   tangent = the face's unit dP/du made ⊥ normal (Gram–Schmidt), or where that fails
 *             (no uv on the face, or dP/du ∥ normal) Duff et al.'s tangent of the normal
 *             (pipeline/math/frames.py tangent_from_normal);
 *   view    = −d;  texel_xy = w·c0 + u·c1 + v·c2 of the face's atlas corners (texels);
 *   object  = the face's object. */

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
                             __global int* object)
{
    int i = get_global_id(0);
    if (i >= n) return;
    int p = pixel[i];
    int f = prim[p];
    float u = hit_u[p], v = hit_v[p];
    float w = 1.0f - u - v;
    float3 d = vload3(p, direction);
    float3 nb = w * vload3(faces[3 * f], vertex_normal)
              + u * vload3(faces[3 * f + 1], vertex_normal)
              + v * vload3(faces[3 * f + 2], vertex_normal);
    float3 sn = nb / fmax(length(nb), 1e-30f);
    if (dot(vload3(f, face_normal), d) > 0.0f) sn = -sn;  /* turned with its face */

    float3 ft = vload3(f, face_tangent);
    float3 t = ft - dot(ft, sn) * sn;
    float len = length(t);
    if (len > TANGENT_MIN_LENGTH) {
        t /= len;
    } else {
        float sign = sn.z >= 0.0f ? 1.0f : -1.0f;
        float a = -1.0f / (sign + sn.z);
        float b = sn.x * sn.y * a;
        t = (float3)(1.0f + sign * sn.x * sn.x * a, sign * b, -sign * sn.x);
    }
    vstore3(sn, i, normal);
    vstore3(t, i, tangent);
    vstore3(-d, i, view);
    vstore2(w * vload2(3 * f, face_uv) + u * vload2(3 * f + 1, face_uv)
            + v * vload2(3 * f + 2, face_uv), i, texel_xy);
    object[i] = face_object[f];
}

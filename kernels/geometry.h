// Ray vs (d-1)-simplex in R^d, the float32 twin of ao4d.bvh.intersect.
// A simplex is DIM+1 float4 rows: the rows of inverse([e1 .. e_{d-1} | n]) and then vertex 0.
// Row DIM-1 gives the height over the hyperplane, rows 0..DIM-2 the barycentrics of vertices
// 1..DIM-1. Coordinates beyond DIM are zero everywhere, so float4 dot products are exact.
#ifndef AO4D_GEOMETRY_H
#define AO4D_GEOMETRY_H

#ifndef DIM
#error "compile with -D DIM=2|3|4"
#endif
#ifndef BARY_EPS
#define BARY_EPS 1e-5f
#endif
#define SIMPLEX_ROWS (DIM + 1)

// true when the ray o + t w hits the simplex with 0 < t <= t_max; *t_hit receives t
inline bool hit_simplex(__global const float4 *s, const float4 o, const float4 w,
                        const float t_max, float *t_hit)
{
    const float4 rel = o - s[DIM];
    const float4 nrow = s[DIM - 1];
    const float t = -dot(nrow, rel) / dot(nrow, w);
    if (!(t > 0.0f && t <= t_max && isfinite(t))) return false;
    const float4 x = rel + t * w;
    float sum = 0.0f;
    for (int i = 0; i < DIM - 1; ++i) {
        const float b = dot(s[i], x);
        if (b < -BARY_EPS) return false;
        sum += b;
    }
    if (1.0f - sum < -BARY_EPS) return false;
    *t_hit = t;
    return true;
}

// slab test of a box against the ray segment (0, t_max]; *t_near receives the entry distance
inline bool hit_box(const float4 lo, const float4 hi, const float4 o, const float4 inv_w,
                    const float t_max, float *t_near)
{
    // fmin/fmax drop the NaN of 0 * inf (ray in a slab plane, parallel to it): conservative
    const float4 t0 = (lo - o) * inv_w, t1 = (hi - o) * inv_w;
    const float4 a = fmin(t0, t1), b = fmax(t0, t1);
#if DIM == 2
    float tn = fmax(a.x, a.y), tf = fmin(b.x, b.y);
#elif DIM == 3
    float tn = fmax(fmax(a.x, a.y), a.z), tf = fmin(fmin(b.x, b.y), b.z);
#else
    float tn = fmax(fmax(a.x, a.y), fmax(a.z, a.w)), tf = fmin(fmin(b.x, b.y), fmin(b.z, b.w));
#endif
    tn = fmax(tn, 0.0f);
    tf = fmin(tf, t_max);
    *t_near = tn;
    return tn <= tf;
}

#endif

// Ray tests in R^DIM, the float32 twins of ao4d.bvh.intersect and of the numpy box test.
// Leaf blocks hold 4 simplices as structure of arrays: float4 number i*DIM + j is entry (i, j)
// of the four inverse matrices inverse([e1 .. e_{d-1} | n]) for i < DIM, and coordinate j of
// their vertex 0 for i = DIM. Row DIM-1 gives the height over the hyperplane, rows 0..DIM-2
// the barycentrics of vertices 1..DIM-1. Unused lanes are all zero: t = 0/0 is never a hit.
#ifndef AO4D_GEOMETRY_H
#define AO4D_GEOMETRY_H

#ifndef DIM
#error "compile with -D DIM=2|3|4"
#endif
#ifndef BARY_EPS
#define BARY_EPS 1e-5f
#endif
#define BLOCK_ROWS ((DIM + 1) * DIM)


// hits of one leaf block: returns the lane of the nearest hit with 0 < t <= t_max, or -1
inline int hit_block(__global const float4 *blk, const float *o, const float *w,
                     const float t_max, float *t_hit)
{
    // explicit fma() only, never contraction chosen per call site: the BVH and brute-force
    // kernels must round alike (fma is exact in every implementation; box tests may contract:
    // their boxes carry a margin)
#pragma OPENCL FP_CONTRACT OFF
    float4 rel[DIM];
    float4 q = (float4)(0.0f), r = (float4)(0.0f);
    for (int j = 0; j < DIM; ++j) {
        rel[j] = (float4)(o[j]) - blk[DIM * DIM + j];
        q = fma(blk[(DIM - 1) * DIM + j], rel[j], q);
        r = fma(blk[(DIM - 1) * DIM + j], (float4)(w[j]), r);
    }
    const float4 t = -q / r;
    int4 ok = isgreater(t, (float4)(0.0f)) & islessequal(t, (float4)(t_max)) & isfinite(t);
    if (!any(ok)) return -1;
    float4 x[DIM];
    for (int j = 0; j < DIM; ++j) x[j] = fma(t, (float4)(w[j]), rel[j]);
    float4 sum = (float4)(0.0f);
    for (int i = 0; i < DIM - 1; ++i) {
        float4 b = (float4)(0.0f);
        for (int j = 0; j < DIM; ++j) b = fma(blk[i * DIM + j], x[j], b);
        ok &= isgreaterequal(b, (float4)(-BARY_EPS));
        sum += b;
    }
    ok &= isgreaterequal((float4)(1.0f) - sum, (float4)(-BARY_EPS));
    if (!any(ok)) return -1;
    float ts[4];
    int oks[4];
    vstore4(t, 0, ts);
    vstore4(ok, 0, oks);
    int lane = -1;
    float best = t_max;
    for (int l = 0; l < 4; ++l) {
        if (oks[l] && (lane < 0 || ts[l] < best)) {
            lane = l;
            best = ts[l];
        }
    }
    *t_hit = best;
    return lane;
}

#ifndef WIDTH
#define WIDTH 8
#endif
#if WIDTH == 8
#define floatW float8
#define intW int8
#define vstoreW vstore8
#elif WIDTH == 16
#define floatW float16
#define intW int16
#define vstoreW vstore16
#else
#error "WIDTH must be 8 or 16"
#endif

// slab test of the WIDTH child boxes of a wide node against the ray segment (0, t_max]:
// boxes[j] / boxes[DIM + j] hold the low / high bound of coordinate j of the children.
// inv_w is finite (load_ray), so no 0 * inf = NaN arises and plain min / max are exact (one
// instruction each on CPUs, where fmin / fmax need extra NaN handling: a third slower
// traversal, measured).
inline intW hit_boxes(__global const floatW *boxes, const float *o, const float *inv_w,
                      const float t_max, floatW *t_near)
{
    floatW tn = (floatW)(0.0f), tf = (floatW)(t_max);
    for (int j = 0; j < DIM; ++j) {
        const floatW t0 = (boxes[j] - o[j]) * inv_w[j];
        const floatW t1 = (boxes[DIM + j] - o[j]) * inv_w[j];
        tn = max(tn, min(t0, t1));
        tf = min(tf, max(t0, t1));
    }
    *t_near = tn;
    return islessequal(tn, tf);
}

#endif

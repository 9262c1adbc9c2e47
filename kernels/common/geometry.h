// Ray tests in R^DIM, the float32 twins of ao4d.bvh.intersect and of the numpy box test.
// Leaf blocks hold LANES simplices as structure of arrays: floatL number i*DIM + j is entry
// (i, j) of the LANES inverse matrices inverse([e1 .. e_{d-1} | n]) for i < DIM, and coordinate j
// of their vertex 0 for i = DIM. Row DIM-1 gives the height over the hyperplane, rows 0..DIM-2
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

// simplices per leaf block: 16 on CPUs, 4 on GPUs (ao4d.ao._block_lanes; why: ao4d.bvh.widen)
#ifndef LANES
#define LANES 16
#endif
#if LANES == 4
#define floatL float4
#define intL int4
#define vstoreL vstore4
#elif LANES == 8
#define floatL float8
#define intL int8
#define vstoreL vstore8
#elif LANES == 16
#define floatL float16
#define intL int16
#define vstoreL vstore16
#else
#error "LANES must be 4, 8 or 16"
#endif


// a leaf block's ray-independent part for origin o: rel[j] = o_j - vertex 0's coordinate j and
// the height q of o over each simplex's hyperplane (the rays of a packet share them)
inline floatL block_origin(__global const floatL *blk, const float *o, floatL *rel)
{
#pragma OPENCL FP_CONTRACT OFF
    floatL q = (floatL)(0.0f);
    for (int j = 0; j < DIM; ++j) {
        rel[j] = (floatL)(o[j]) - blk[DIM * DIM + j];
        q = fma(blk[(DIM - 1) * DIM + j], rel[j], q);
    }
    return q;
}

// hits of one leaf block by the ray with direction w from the origin of block_origin's rel and q:
// the lane of the nearest hit with 0 < t <= t_max, or -1
inline int hit_block_at(__global const floatL *blk, const floatL *rel, const floatL q,
                        const float *w, const float t_max, float *t_hit)
{
    // explicit fma() only, never contraction chosen per call site: the BVH and brute-force
    // kernels must round alike (fma is exact in every implementation; box tests may contract:
    // their boxes carry a margin)
#pragma OPENCL FP_CONTRACT OFF
    floatL r = (floatL)(0.0f);
    for (int j = 0; j < DIM; ++j) r = fma(blk[(DIM - 1) * DIM + j], (floatL)(w[j]), r);
    const floatL t = -q / r;
    // t <= min(t_max, FLT_MAX) also rejects t = inf (r = 0) and NaN (q = r = 0: unused lanes)
    intL ok = isgreater(t, (floatL)(0.0f)) & islessequal(t, (floatL)(fmin(t_max, FLT_MAX)));
    if (!any(ok)) return -1;
    floatL x[DIM];
    for (int j = 0; j < DIM; ++j) x[j] = fma(t, (floatL)(w[j]), rel[j]);
    floatL sum = (floatL)(0.0f);
    for (int i = 0; i < DIM - 1; ++i) {
        floatL b = (floatL)(0.0f);
        for (int j = 0; j < DIM; ++j) b = fma(blk[i * DIM + j], x[j], b);
        ok &= isgreaterequal(b, (floatL)(-BARY_EPS));
        sum += b;
    }
    ok &= isgreaterequal((floatL)(1.0f) - sum, (floatL)(-BARY_EPS));
    if (!any(ok)) return -1;
    float ts[LANES];
    int oks[LANES];
    vstoreL(t, 0, ts);
    vstoreL(ok, 0, oks);
    int lane = -1;
    float best = t_max;
    for (int l = 0; l < LANES; ++l) {
        if (oks[l] && (lane < 0 || ts[l] < best)) {
            lane = l;
            best = ts[l];
        }
    }
    *t_hit = best;
    return lane;
}

// hits of one leaf block: returns the lane of the nearest hit with 0 < t <= t_max, or -1
inline int hit_block(__global const floatL *blk, const float *o, const float *w,
                     const float t_max, float *t_hit)
{
    floatL rel[DIM];
    const floatL q = block_origin(blk, o, rel);
    return hit_block_at(blk, rel, q, w, t_max, t_hit);
}

#ifndef WIDTH
#define WIDTH 8
#endif
#if WIDTH == 8
#define floatW float8
#define intW int8
#define vstoreW vstore8
#define vloadW vload8
#define convert_intW convert_int8
#define LANE_BITS_W (int8)(1, 2, 4, 8, 16, 32, 64, 128)
#elif WIDTH == 16
#define floatW float16
#define intW int16
#define vstoreW vstore16
#define vloadW vload16
#define convert_intW convert_int16
#define LANE_BITS_W (int16)(1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384, 32768)
#else
#error "WIDTH must be 8 or 16"
#endif

// bit s set where lane s of `lanes` is nonzero (true)
inline int lane_bits(const intW lanes)
{
    const intW b = lanes & LANE_BITS_W;
#if WIDTH == 16
    const int8 b8 = b.lo | b.hi;
#else
    const int8 b8 = b;
#endif
    const int4 b4 = b8.lo | b8.hi;
    const int2 b2 = b4.lo | b4.hi;
    return b2.x | b2.y;
}

// slab test of the WIDTH child boxes of a wide node against the ray segment (0, t_max]:
// boxes[j] / boxes[DIM + j] hold the low / high bound of coordinate j of the children. The ray
// (load_ray) gives, per coordinate, the row of the entry bound (near: low bound when the
// direction is positive) and of the exit bound (far), the finite inverse direction inv_w and
// o_inv = o * inv_w, so that each slab costs one fma per bound and no min / max of the two.
// fma(box, inv_w, -o_inv) errs by up to |o| * 2^-24 in box coordinates: the boxes' margin
// covers it (ao4d.bvh._BOX_FMA_MARGIN). inv_w is finite, so no 0 * inf = NaN arises and plain
// min / max are exact (fmin / fmax need extra NaN handling: a third slower, measured).
inline intW hit_boxes(__global const floatW *boxes, const int *near, const int *far,
                      const float *inv_w, const float *o_inv, const float t_max, floatW *t_near)
{
    floatW tn = (floatW)(0.0f), tf = (floatW)(t_max);
    for (int j = 0; j < DIM; ++j) {
        tn = max(tn, fma(boxes[near[j]], (floatW)(inv_w[j]), (floatW)(-o_inv[j])));
        tf = min(tf, fma(boxes[far[j]], (floatW)(inv_w[j]), (floatW)(-o_inv[j])));
    }
    *t_near = tn;
    return islessequal(tn, tf);
}

#endif

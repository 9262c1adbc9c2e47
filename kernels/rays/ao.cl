// Ambient occlusion on simplex meshes in R^DIM (DIM = 2, 3 or 4).
// Host side: ao4d/ao.py. Vectors are float4 with zeros beyond DIM.
// vec_type_hint(float4) keeps CPU runtimes (Intel's) from vectorising across work-items: rays
// traverse the tree divergently, so masked lanes across rays run far slower than scalar
// work-items that use float4/float8 within one ray (figures: the benchmarks log). GPUs ignore
// the hint.
#include "bvh/bvh.h"
#include "common/sampling.h"

inline int trace(const int use_bvh, __global const floatW *boxes, __global const int *children,
                 __global const floatL *blocks, const int n_blocks, const float4 o,
                 const float4 w, const float t_max, const int any_hit, float *t_out VISITS_PARAM)
{
    if (use_bvh) return trace_bvh(boxes, children, blocks, o, w, t_max, any_hit, t_out VISITS_ARG);
    return trace_brute(blocks, n_blocks, o, w, t_max, any_hit, t_out);
}

// occluded-ray count of point i over `samples` cosine-weighted directions
inline int occlusion_count(const int use_bvh, __global const floatW *boxes,
                           __global const int *children, __global const floatL *blocks,
                           const int n_blocks, const float4 p, const float4 n, const uint index,
                           __global const uint *table, const int samples, const uint seed,
                           const float offset, const float max_distance VISITS_PARAM)
{
    uint shift[DIM - 1];
    float4 frame[DIM - 1];
    point_sampling(n, index, seed, shift, frame);
    // start above the surface: a ray must not hit the simplices the point lies on
    const float4 o = p + offset * n;
    int hits = 0;
    for (int s = 0; s < samples; ++s) {
        const float4 w = cosine_direction(n, frame, table, s, shift);
        float t;
        hits += trace(use_bvh, boxes, children, blocks, n_blocks, o, w, max_distance, 1, &t VISITS_ARG) >= 0;
    }
    return hits;
}

// the same count, the rays traced PACKET at a time from their shared origin (trace_packet)
inline int occlusion_count_packet(__global const floatW *boxes, __global const int *children,
                                  __global const floatL *blocks, const float4 p, const float4 n,
                                  const uint index, __global const uint *table, const int samples,
                                  const uint seed, const float offset,
                                  const float max_distance VISITS_PARAM)
{
    uint shift[DIM - 1];
    float4 frame[DIM - 1];
    point_sampling(n, index, seed, shift, frame);
    const float4 o = p + offset * n;
    float origin[4];
    vstore4(o, 0, origin);
    PacketRay rays[PACKET];
    int hits = 0;
    for (int s0 = 0; s0 < samples; s0 += PACKET) {
        const int count = min(PACKET, samples - s0);
        for (int k = 0; k < count; k += 8) {
            float8 w[DIM];
            cosine_directions8(n, frame, table, s0 + k, samples, shift, w);
            load_packet_rays8(origin, w, min(8, count - k), rays + k);
        }
        const pmask active = count == PACKET ? ~(pmask)0 : (((pmask)1 << count) - 1);
        hits += (int)popcount(trace_packet(boxes, children, blocks, origin, rays, active,
                                           max_distance VISITS_ARG));
    }
    return hits;
}

// The parameters of the two tree AO kernels (the host passes the same arguments to either)
// and, with -D COUNT_VISITS, their per-point output: the four counters of bvh.h.
#ifdef COUNT_VISITS
#define VISITS_OUT_PARAM , __global int *visits_out
#define VISITS_STORE(i) for (int k = 0; k < 4; ++k) visits_out[4 * (i) + k] = visits[k]
#else
#define VISITS_OUT_PARAM
#define VISITS_STORE(i)
#endif
#define AO_TREE_PARAMS                                                                              \
    __global const floatW *boxes, __global const int *children, __global const floatL *blocks,     \
    __global const float4 *points, __global const float4 *normals, __global const uint *index,     \
    __global const uint *table, const int samples, const uint seed, const float offset,            \
    const float max_distance, __global int *counts VISITS_OUT_PARAM

// occlusion counts, PACKET rays of a point at a time (the default AO kernel)
__kernel __attribute__((vec_type_hint(float4))) void ao_bvh(AO_TREE_PARAMS)
{
    const size_t i = get_global_id(0);
    VISITS_DECL
    counts[i] = occlusion_count_packet(boxes, children, blocks, points[i], normals[i], index[i],
                                       table, samples, seed, offset, max_distance VISITS_ARG);
    VISITS_STORE(i);
}

// the same counts, one ray at a time (trace_any): the reference the packet kernel must equal
__kernel __attribute__((vec_type_hint(float4))) void ao_bvh_rays(AO_TREE_PARAMS)
{
    const size_t i = get_global_id(0);
    VISITS_DECL
    counts[i] = occlusion_count(1, boxes, children, blocks, 0, points[i], normals[i], index[i],
                                table, samples, seed, offset, max_distance VISITS_ARG);
    VISITS_STORE(i);
}

__kernel __attribute__((vec_type_hint(float4))) void ao_brute(__global const floatL *blocks, const int n_blocks,
                       __global const float4 *points, __global const float4 *normals,
                       __global const uint *index, __global const uint *table, const int samples,
                       const uint seed, const float offset, const float max_distance,
                       __global int *counts)
{
    const size_t i = get_global_id(0);
    VISITS_DECL
    counts[i] = occlusion_count(0, 0, 0, blocks, n_blocks, points[i], normals[i], index[i],
                                table, samples, seed, offset, max_distance VISITS_ARG);
}

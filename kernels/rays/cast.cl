// Ray casting on simplex meshes in R^DIM (DIM = 2, 3 or 4): closest or any hit of given rays, one
// ray per work-item (host side: ao4d.rays.launches). Vectors are float4 with zeros beyond DIM;
// vec_type_hint(float4) as in ao.cl.
#include "bvh/bvh.h"

// the debug counters of bvh.h are not written by these kernels
// one ray per work-item: closest (any_hit = 0) or any hit within max_distance; hit_out is
// LANES * leaf block + lane (the host maps it to a simplex) or -1
__kernel __attribute__((vec_type_hint(float4))) void cast_bvh(__global const floatW *boxes, __global const int *children,
                       __global const floatL *blocks, __global const float4 *origins, __global const float4 *directions,
                       const float max_distance, const int any_hit, __global float *t_out,
                       __global int *hit_out)
{
    const size_t i = get_global_id(0);
    VISITS_DECL
    float t;
    hit_out[i] = trace_bvh(boxes, children, blocks, origins[i], directions[i], max_distance,
                           any_hit, &t VISITS_ARG);
    t_out[i] = t;
}

__kernel __attribute__((vec_type_hint(float4))) void cast_brute(__global const floatL *blocks, const int n_blocks,
                         __global const float4 *origins, __global const float4 *directions,
                         const float max_distance, const int any_hit, __global float *t_out,
                         __global int *hit_out)
{
    const size_t i = get_global_id(0);
    float t;
    hit_out[i] = trace_brute(blocks, n_blocks, origins[i], directions[i], max_distance, any_hit,
                             &t);
    t_out[i] = t;
}

// -- cast_rays' rays as the caller gave them (-D RAY_T=float|double; cl_khr_fp64) -------------
#ifdef RAY_T
#include "rays/rows.h"

#define CAST_ROWS_PARAMS                                                                            \
    __global const RAY_T *origins, __global const RAY_T *directions,                               \
    __global const double *frame, const float max_distance, const int any_hit, __global int *hit_out

// cast_bvh on the caller's rows (launch-sized copies of them): hit_out as cast_bvh's, or -2 for a zero-length direction
__kernel __attribute__((vec_type_hint(float4))) void cast_rows_bvh(
    __global const floatW *boxes, __global const int *children, __global const floatL *blocks,
    CAST_ROWS_PARAMS)
{
    const size_t i = get_global_id(0);
    VISITS_DECL
    float4 o, w;
    float t;
    hit_out[i] = map_ray(origins, directions, frame, i, &o, &w)
                     ? trace_bvh(boxes, children, blocks, o, w, max_distance, any_hit, &t VISITS_ARG)
                     : -2;
}

// cast_brute on the caller's rows (as cast_rows_bvh)
__kernel __attribute__((vec_type_hint(float4))) void cast_rows_brute(
    __global const floatL *blocks, const int n_blocks, CAST_ROWS_PARAMS)
{
    const size_t i = get_global_id(0);
    float4 o, w;
    float t;
    hit_out[i] = map_ray(origins, directions, frame, i, &o, &w)
                     ? trace_brute(blocks, n_blocks, o, w, max_distance, any_hit, &t)
                     : -2;
}

// the float4 rays cast_rows_bvh traces (for tests: the bits of _Rays.chunk); w = 0 for a
// zero-length direction
__kernel void map_rays(__global const RAY_T *origins, __global const RAY_T *directions,
                       __global const double *frame, __global float4 *o_out, __global float4 *w_out)
{
    const size_t i = get_global_id(0);
    float4 o = (float4)(0.0f), w = (float4)(0.0f);
    map_ray(origins, directions, frame, i, &o, &w);
    o_out[i] = o;
    w_out[i] = w;
}
#endif

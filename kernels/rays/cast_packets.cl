// cast_rays' any-hit rays that share an origin, traced PACKET at a time (trace_packet), as the
// AO kernel traces a point's rays: a node is fetched once per packet, not once per ray. Host
// side: ao4d.rays.launches._trace_opencl, which finds runs of rows with bit-identical origins.
// Each ray's hit / miss answer is trace_any's (bvh.h: the packet makes the same tests with the
// same arithmetic), and each row is mapped by map_ray (rows.h) and load_ray (bvh.h), as
// cast_rows_bvh maps and loads it, so every ray is traced from the same float32 bits; the hit
// reported for a ray may be another of its hits (any hit).
//
// Compile with -D DIM, WIDTH, LANES, STACK_SIZE, PACKET, BARY_EPS as ao.cl, and -D RAY_T.
#define PACKET_HITS
#include "bvh/bvh.h"
#include "rays/rows.h"

// packets[i] = (first row, rows): rays of one origin; hit_out as cast_rows_bvh's (-2: a
// zero-length direction, which the host names)
__kernel __attribute__((vec_type_hint(float4))) void cast_packets_bvh(
    __global const floatW *boxes, __global const int *children, __global const floatL *blocks,
    __global const RAY_T *origins, __global const RAY_T *directions, __global const double *frame,
    __global const int2 *packets, const float max_distance, __global int *hit_out)
{
    const int2 packet = packets[get_global_id(0)];
    float o[4] = {0.0f, 0.0f, 0.0f, 0.0f};  // the shared origin: every row maps it alike
    PacketRay rays[PACKET];
    int hit_of[PACKET];
    pmask active = 0;
    for (int k = 0; k < packet.y; ++k) {
        const size_t row = (size_t)packet.x + k;
        float4 o4, w4;
        hit_of[k] = -1;
        if (!map_ray(origins, directions, frame, row, &o4, &w4)) {
            hit_out[row] = -2;
            continue;
        }
        Ray ray;
        load_ray(o4, w4, &ray);
        for (int j = 0; j < DIM; ++j) {
            o[j] = ray.o[j];
            rays[k].w[j] = ray.w[j];
            rays[k].inv_w[j] = ray.inv_w[j];
            rays[k].o_inv[j] = ray.o_inv[j];
            rays[k].near[j] = ray.near[j];
            rays[k].far[j] = ray.far[j];
        }
        active |= (pmask)1 << k;
    }
    if (active) trace_packet(boxes, children, blocks, o, rays, active, max_distance, hit_of);
    for (int k = 0; k < packet.y; ++k)
        if ((active >> k) & 1) hit_out[(size_t)packet.x + k] = hit_of[k];
}

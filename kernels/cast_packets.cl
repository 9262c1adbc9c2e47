// cast_rays' any-hit rays that share an origin, traced PACKET at a time (trace_packet), as the
// AO kernel traces a point's rays: a node is fetched once per packet, not once per ray. Host
// side: ao4d.raycast._trace_opencl, which finds runs of rows with bit-identical origins.
// Each ray's hit / miss answer is trace_any's (bvh.h: the packet makes the same tests with the
// same arithmetic), and the rows are mapped into the tree's frame with map_ray's operations
// (kernels/ao.cl), so every ray is traced from the same float32 bits as by cast_rows_bvh; the
// hit reported for a ray may be another of its hits (any hit).
//
// Compile with -D DIM, WIDTH, LANES, STACK_SIZE, PACKET, BARY_EPS as ao.cl, and -D RAY_T.
#define PACKET_HITS
#include "bvh.h"
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

// packets[i] = (first row, rows): rays of one origin; hit_out as cast_rows_bvh's (-2: a
// zero-length direction, which the host names)
__kernel __attribute__((vec_type_hint(float4))) void cast_packets_bvh(
    __global const floatW *boxes, __global const int *children, __global const floatL *blocks,
    __global const RAY_T *origins, __global const RAY_T *directions, __global const double *frame,
    __global const int2 *packets, const float max_distance, __global int *hit_out)
{
#pragma OPENCL FP_CONTRACT OFF
    const int2 packet = packets[get_global_id(0)];
    float o[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    for (int j = 0; j < DIM; ++j)
        o[j] = (float)(((double)origins[(size_t)packet.x * DIM + j] - frame[j]) * frame[DIM]);
    PacketRay rays[PACKET];
    int hit_of[PACKET];
    pmask active = 0;
    for (int k = 0; k < packet.y; ++k) {
        const size_t row = (size_t)packet.x + k;
        double length2 = 0.0;
        for (int j = 0; j < DIM; ++j) {
            const double x = directions[row * DIM + j];
            length2 += x * x;
        }
        hit_of[k] = -1;
        if (!(length2 > 0.0)) {
            hit_out[row] = -2;
            continue;
        }
        const double inv_length = (double)(float)(1.0 / sqrt(length2));
        for (int j = 0; j < DIM; ++j) {
            const float w = (float)((double)directions[row * DIM + j] * inv_length);
            // load_ray's box-test constants, the same bits
            const float tiny = fmax(1e-30f, fabs(o[j]) * 0x1p-100f);
            const float inv_w = 1.0f / (fabs(w) > tiny ? w : copysign(tiny, w));
            rays[k].w[j] = w;
            rays[k].inv_w[j] = inv_w;
            rays[k].o_inv[j] = o[j] * inv_w;
            const int negative = signbit(inv_w) != 0;
            rays[k].near[j] = negative ? DIM + j : j;
            rays[k].far[j] = negative ? j : DIM + j;
        }
        active |= (pmask)1 << k;
    }
    if (active) trace_packet(boxes, children, blocks, o, rays, active, max_distance, hit_of);
    for (int k = 0; k < packet.y; ++k)
        if ((active >> k) & 1) hit_out[(size_t)packet.x + k] = hit_of[k];
}

// The directions the AO kernels trace (rays/ao.cl), for tests: they must equal
// ao4d.sampling.cosine_hemisphere bit for bit, eight at a time as the packet kernel makes them
// and one at a time as the per-ray kernel does. Host side: ao4d.rays.launches.sample_directions.
#include "common/sampling.h"

// the parameters of the two direction kernels below (tests call them alike)
#define DIRECTIONS_PARAMS                                                                           \
    __global const float4 *normals, __global const uint *index, __global const uint *table,        \
    const int samples, const uint seed, __global float4 *out

// the directions of sample_directions, generated eight at a time (cosine_directions8) as the
// packet kernel does: for tests, which check that they are the same bits
__kernel void sample_directions8(DIRECTIONS_PARAMS)
{
    const size_t i = get_global_id(0);
    uint shift[DIM - 1];
    float4 frame[DIM - 1];
    point_sampling(normals[i], index[i], seed, shift, frame);
    for (int s0 = 0; s0 < samples; s0 += 8) {
        float8 w[DIM];
        cosine_directions8(normals[i], frame, table, s0, samples, shift, w);
        float c[4][8] = {{0.0f}};
        for (int j = 0; j < DIM; ++j) vstore8(w[j], 0, c[j]);
        for (int k = 0; k < min(8, samples - s0); ++k)
            out[i * samples + s0 + k] = (float4)(c[0][k], c[1][k], c[2][k], c[3][k]);
    }
}

// the directions ao_* trace for each point (for tests: must equal ao4d.sampling.cosine_hemisphere)
__kernel void sample_directions(DIRECTIONS_PARAMS)
{
    const size_t i = get_global_id(0);
    uint shift[DIM - 1];
    float4 frame[DIM - 1];
    point_sampling(normals[i], index[i], seed, shift, frame);
    for (int s = 0; s < samples; ++s)
        out[i * samples + s] = cosine_direction(normals[i], frame, table, s, shift);
}

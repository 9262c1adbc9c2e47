// Cosine-weighted hemisphere directions: the float32 twin of ao4d/sampling.py (same integers,
// same formulas), so both backends trace the same rays. Needs DIM in {2, 3, 4}.
#ifndef AO4D_SAMPLING_H
#define AO4D_SAMPLING_H

#define SAMPLE_BITS 24
#define SAMPLE_MASK 0xFFFFFFu
#define SAMPLE_SCALE (1.0f / 16777216.0f)

// "lowbias32" integer hash (C. Wellons); ao4d.sampling.hash32
inline uint hash32(uint x)
{
    x ^= x >> 16;
    x *= 0x7FEB352Du;
    x ^= x >> 15;
    x *= 0x846CA68Bu;
    x ^= x >> 16;
    return x;
}

// Cranley-Patterson offset of coordinate k for the point with global index `index`
inline uint point_shift(uint index, uint seed, uint k)
{
    const uint base = hash32(hash32(index) ^ seed);
    return hash32(base + k) >> (32 - SAMPLE_BITS);
}

inline float unit_coordinate(uint table_value, uint shift)
{
    return ((float)((table_value + shift) & SAMPLE_MASK) + 0.5f) * SAMPLE_SCALE;
}

// Householder tangent frame of unit n: t_j = e_j - n_j (n + s e_last) / (1 + |n_last|)
inline float4 tangent(const float4 n, const int j)
{
#if DIM == 2
    const float nl = n.y;
#elif DIM == 3
    const float nl = n.z;
#else
    const float nl = n.w;
#endif
    const float s = nl >= 0.0f ? 1.0f : -1.0f;
    const float a = 1.0f / (1.0f + fabs(nl));
    float4 v = n;
#if DIM == 2
    v.y += s;
#elif DIM == 3
    v.z += s;
#else
    v.w += s;
#endif
    const float nj = j == 0 ? n.x : (j == 1 ? n.y : n.z);
    float4 t = -(nj * a) * v;
    if (j == 0) t.x += 1.0f;
    else if (j == 1) t.y += 1.0f;
    else t.z += 1.0f;
    return t;
}

// the DIM-1 tangent vectors of n, computed once per point
inline void tangent_frame(const float4 n, float4 *frame)
{
    for (int j = 0; j < DIM - 1; ++j) frame[j] = tangent(n, j);
}

// what every direction of one point needs: the Cranley-Patterson shifts of point `index` and
// the tangent frame of its unit normal n
inline void point_sampling(const float4 n, const uint index, const uint seed, uint *shift, float4 *frame)
{
    for (int k = 0; k < DIM - 1; ++k) shift[k] = point_shift(index, seed, (uint)k);
    tangent_frame(n, frame);
}

// Unit coordinates u0, u1 (, u2) -> b0, b1 (, b2): a point of the unit disc (3D) or ball (4D),
// uniform, and `up`, the height above it on the unit sphere: the cosine-weighted direction in
// the tangent frame (Malley). One text for scalar (T = float) and eight-lane (T = float8)
// samples, so both compute the same operations in the same order. sincos: one shared range
// reduction where separate sin and cos would do two.
#define DISC_POINT(T)                                                   \
    const T r = sqrt(u0);                                               \
    T cos_phi;                                                          \
    const T sin_phi = sincos(6.283185307179586f * u1, &cos_phi);        \
    const T b0 = r * cos_phi, b1 = r * sin_phi;                         \
    const T up = sqrt(fmax(0.0f, 1.0f - (b0 * b0 + b1 * b1)))
#define BALL_POINT(T)                                                   \
    const T r = cbrt(u0);                                               \
    const T z = 1.0f - 2.0f * u1;                                       \
    const T sz = sqrt(fmax(0.0f, 1.0f - z * z));                        \
    T cos_phi;                                                          \
    const T sin_phi = sincos(6.283185307179586f * u2, &cos_phi);        \
    const T b0 = r * sz * cos_phi, b1 = r * sz * sin_phi, b2 = r * z;   \
    const T up = sqrt(fmax(0.0f, 1.0f - (b0 * b0 + b1 * b1 + b2 * b2)))

// direction of sample `s` for a point with normal n and tangent frame `frame`;
// table holds (samples, DIM-1) 24-bit ints
inline float4 cosine_direction(const float4 n, const float4 *frame, __global const uint *table,
                               const int s, const uint *shift)
{
#if DIM == 2
    const float b0 = 2.0f * unit_coordinate(table[s], shift[0]) - 1.0f;
    const float up = sqrt(fmax(0.0f, 1.0f - b0 * b0));
    return b0 * frame[0] + up * n;
#elif DIM == 3
    const float u0 = unit_coordinate(table[2 * s], shift[0]);
    const float u1 = unit_coordinate(table[2 * s + 1], shift[1]);
    DISC_POINT(float);
    return b0 * frame[0] + b1 * frame[1] + up * n;
#else
    const float u0 = unit_coordinate(table[3 * s], shift[0]);
    const float u1 = unit_coordinate(table[3 * s + 1], shift[1]);
    const float u2 = unit_coordinate(table[3 * s + 2], shift[2]);
    BALL_POINT(float);
    return b0 * frame[0] + b1 * frame[1] + b2 * frame[2] + up * n;
#endif
}

// cosine_direction for the eight samples s0 .. s0 + 7 at once, one sample per vector lane (the
// same operations on float8: vector math functions, not one scalar call per sample); lanes past
// the last sample repeat it. w[j] receives coordinate j of the eight directions.
inline void cosine_directions8(const float4 n, const float4 *frame, __global const uint *table,
                               const int s0, const int samples, const uint *shift, float8 *w)
{
    uint u[DIM - 1][8];
    for (int k = 0; k < 8; ++k) {
        const int s = min(s0 + k, samples - 1);
        for (int c = 0; c < DIM - 1; ++c) u[c][k] = table[(DIM - 1) * s + c];
    }
#define UNIT8(c) ((convert_float8(((vload8(0, u[c]) + (uint8)(shift[c])) & (uint8)(SAMPLE_MASK))) \
                   + 0.5f) * SAMPLE_SCALE)
#if DIM == 2
    const float8 b0 = 2.0f * UNIT8(0) - 1.0f;
    const float8 up = sqrt(fmax(0.0f, 1.0f - b0 * b0));
#elif DIM == 3
    const float8 u0 = UNIT8(0), u1 = UNIT8(1);
    DISC_POINT(float8);
#else
    const float8 u0 = UNIT8(0), u1 = UNIT8(1), u2 = UNIT8(2);
    BALL_POINT(float8);
#endif
#undef UNIT8
    float f[DIM][4];
    for (int k = 0; k < DIM - 1; ++k) vstore4(frame[k], 0, f[k]);
    vstore4(n, 0, f[DIM - 1]);
    for (int j = 0; j < DIM; ++j) {
#if DIM == 2
        w[j] = b0 * f[0][j] + up * f[1][j];
#elif DIM == 3
        w[j] = b0 * f[0][j] + b1 * f[1][j] + up * f[2][j];
#else
        w[j] = b0 * f[0][j] + b1 * f[1][j] + b2 * f[2][j] + up * f[3][j];
#endif
    }
}

#endif

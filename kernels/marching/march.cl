// Marching extraction of one slab of grid layers (ao4d/marching/cells_device.py drives it): the whole
// march, from the values as stored to the final vertex positions and simplices.
//
// The slab is a C-order engine grid of shape (n0, n1, ..., n_{DIM-1}); n0 = cell layers + 1.
// sign, classify and interpolate run one work-item per point (per new vertex); the chunk passes
// one work-item per chunk of CHUNK consecutive points, walked in order 16 points at a time (a
// vector of 16 cases or masks that are all zero, most of the grid, is skipped at once).
// Per-chunk counts plus an exclusive scan over chunks give each point and cell its place in the
// output in the numpy engine's order (ao4d/marching/cells.py):
//
//   sign        per point: 1 where the value is positive (one comparison in the value's own
//               type against a threshold that makes it exact: ao4d/marching/cells.py's threshold),
//               and a flag for NaN and infinities
//   classify    per point: the cell's case (bit v = corner v positive; 0 when no simplex) and
//               the bit mask of the crossed edges starting here that are new in this slab (not
//               carried from the slab below)
//   count       per chunk: simplices, active cells and new vertices (in-plane and not)
//   scan_chunks exclusive scan of the chunk counts in blocks of SCAN_BLOCK chunks
//   scan_blocks exclusive scan of the block totals (one work-item; a few hundred blocks)
//   layer_prefix  per layer: the new vertices before its first point (in-plane and not)
//   number      new vertices numbered, their keys compacted, the top layer's in-plane vertices
//               remembered for the next slab (carry); each block of 16 points with new vertices
//               gets the counts before it (vblock; in 4D, each point its first index instead)
//   emit        the simplices of every active cell, rows of the cell table in order, each edge
//               replaced by its vertex index (new_vertex)
//   interpolate every new vertex's position, with the numpy engine's float64 operations
//
// The chunk passes and emit skip what is empty 16 points at a time: classify tests a block's
// corner signs as bytes before any lane arithmetic, count and number visit only a block's
// nonzero lanes (FOR_NONZERO), emit counts a block's vertices below a point with popcounts
// (lanes_before).
//
// Vertex order: the numpy engine numbers the new vertices of each of its slabs (PERIOD layers)
// in (point, direction) order, and the in-plane vertices of the layer two of its slabs share
// belong to the lower slab. So in a layer z > 0 with z % PERIOD == 0 (a *boundary*), the
// in-plane vertices come first (point order), then the others; every other layer interleaves
// them by (point, direction). A device slab of any multiple of PERIOD layers, numbering so,
// gives the numpy engine's arrays.
//
// A crossed edge (ends of different sign) inside the slab is used by every cell case that
// contains it (checked for every table by tests/test_cells_device.py), so "used" is read off the
// signs without marking. Work-group sizes are left to the runtime; no local memory.
//
// Defines: DIM (2, 3, 4), NDIRS (edge directions of the table), CHUNK (a multiple of 16),
// SCAN_BLOCK; VTYPE, the values' stored type (VFLOAT: 1 for float or double), and VKIND: 0
// compared as stored, 1 half (stored as half, compared as float), 2 double without cl_khr_fp64
// (stored bits compared as ordered integers); FP64: 1 interpolates in double (the numpy
// engine's bits), 0 in float (written as double bits).

#pragma OPENCL FP_CONTRACT OFF

#if FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real_t;
#else
typedef float real_t;
#endif

#if VKIND == 1
typedef half value_t;
typedef float cmp_t;
#define LOAD_CMP(a, i) vload_half((i), (a))
#define LOAD_REAL(a, i) ((real_t)vload_half((i), (a)))
#elif VKIND == 2
typedef ulong value_t;
typedef long cmp_t;
// IEEE doubles, ordered as signed integers (finite values and infinities)
#define LOAD_CMP(a, i) double_key((a)[i])
#define LOAD_REAL(a, i) double_to_float((a)[i])
inline long double_key(ulong b)
{
    return (long)b >= 0 ? (long)b : (long)(b ^ 0x7fffffffffffffffUL);
}
// truncated to float (results below float's normal range flushed to zero)
inline float double_to_float(ulong b)
{
    const uint hi = (uint)(b >> 32);
    const uint s = hi & 0x80000000u;
    const int e = (int)((hi >> 20) & 0x7ff);
    const uint m = (uint)((b >> 29) & 0x7fffff);
    if (e == 0x7ff) return as_float(s | 0x7f800000u | (m ? 0x400000u : 0u));
    const int ef = e - 1023 + 127;
    if (ef >= 255) return as_float(s | 0x7f800000u);
    if (ef <= 0) return as_float(s);
    return as_float(s | ((uint)ef << 23) | m);
}
#else
typedef VTYPE value_t;
typedef VTYPE cmp_t;
#define LOAD_CMP(a, i) ((a)[i])
#define LOAD_REAL(a, i) ((real_t)(a)[i])
#endif

#if FP64
typedef double out_t;
#define STORE_REAL(out, i, x) ((out)[i] = (x))
#else
typedef uint2 out_t;  // the float result's double bits (lo, hi)
inline uint2 float_bits_as_double(float x)
{
    const uint b = as_uint(x);
    const uint s = b & 0x80000000u, e = (b >> 23) & 0xff, m = b & 0x7fffff;
    if (e == 0) return (uint2)(0u, s);  // zero (float denormals flushed)
    const uint de = e == 255 ? 0x7ffu : e + 896u;
    return (uint2)(m << 29, s | (de << 20) | (m >> 3));
}
#define STORE_REAL(out, i, x) ((out)[i] = float_bits_as_double(x))
#endif

#define NCORNERS (1 << DIM)

#if DIM == 4
typedef ushort case_t;
#else
typedef uchar case_t;
#endif

#if NDIRS > 8
typedef ushort vmask_t;
#else
typedef uchar vmask_t;
#endif


// The passes that walk chunks read 16 values at a time themselves: the hint tells compilers that
// vectorise across work-items (Intel's CPU runtime) that the kernel is vectorised already.
#define CHUNK_KERNEL __attribute__((vec_type_hint(uchar16)))

// Offset of the corner (or edge direction) with user bits v from a point: s0 .. s3 are the
// strides of user axes 0 .. 3 (ao4d/marching/cells.py's corner_offsets).
inline int corner_offset(const int v, const int s0, const int s1, const int s2, const int s3)
{
    return (v & 1) * s0 + ((v >> 1) & 1) * s1
#if DIM > 2
        + ((v >> 2) & 1) * s2
#endif
#if DIM > 3
        + ((v >> 3) & 1) * s3
#endif
        ;
}

// The 16 values of `size` bytes (1 or 2, a compile-time constant) from byte a are all zero.
inline int zero16(__global const uchar *a, const int size)
{
    ulong2 u = as_ulong2(vload16(0, a));
    ulong any = u.s0 | u.s1;
    if (size == 2) {
        ulong2 w = as_ulong2(vload16(1, a));
        any |= w.s0 | w.s1;
    }
    return any == 0;
}

// The 16 values (cases or vertex masks) at chunk position i of array a are all zero.
#define ZERO16(a, i) zero16((__global const uchar *)((a) + (i)), sizeof(*(a)))

// FOR_NONZERO(a, i, x) { ... }: the body runs for each x in i .. i + 15 whose value a[x] (1 or 2
// bytes; i a multiple of 16) is not zero, in increasing order, read off the block as two or four
// 64-bit words (the lowest set bit's lane first), not lane by lane: an active block holds a few
// nonzero lanes among 16 (at 256^3 the number pass took about a quarter less time). `continue` in the
// body goes on with the next lane; `break` must not be used. Devices that are not little-endian
// walk every lane.
#if defined(__ENDIAN_LITTLE__) && __ENDIAN_LITTLE__
#define LANE_BITS(a) (8 * (int)sizeof(*(a)))
#define FOR_NONZERO(a, i, x)                                                                      \
    for (int w_ = 0; w_ < 2 * (int)sizeof(*(a)); ++w_)                                          \
        for (ulong m_ = ((__global const ulong *)((a) + (i)))[w_], l_ = 0;                      \
             m_ != 0 && ((l_ = (ulong)(63 - clz(m_ & (~m_ + 1)))), 1);                          \
             m_ &= ~((((ulong)1 << LANE_BITS(a)) - 1) << (l_ & ~(ulong)(LANE_BITS(a) - 1))))    \
            for (int x = (i) + w_ * (64 / LANE_BITS(a)) + (int)(l_ / LANE_BITS(a)), o_ = 1; o_; o_ = 0)
#else
#define FOR_NONZERO(a, i, x) \
    for (int x = (i), e_ = (i) + 16; x < e_; ++x) \
        if ((a)[x] != 0)
#endif

// Add the new in-plane (*vi) and other (*va) vertices at points x0 .. x1 - 1 (vertex masks).
inline void count_vertices(__global const vmask_t *vmask, const int x0, const int x1,
                           const int in_plane, int *vi, int *va)
{
    for (int x = x0; x < x1; ++x) {
        const int m = vmask[x];
        *vi += popcount(m & in_plane);
        *va += popcount(m & ~in_plane);
    }
}

// Direction j's mask (cube corner): the cube table has the d axis directions, the Kuhn table
// every non-empty mask, both in increasing order (ao4d/marching/cells.py's plan.dirs).
#if NDIRS == DIM
#define DIR_MASK(j) (1 << (j))
#else
#define DIR_MASK(j) ((j) + 1)
#endif

#if DIM == 4
#define CONVERT_CASE16 convert_ushort16
#else
#define CONVERT_CASE16 convert_uchar16
#endif
#if NDIRS > 8
#define CONVERT_VMASK16 convert_ushort16
#else
#define CONVERT_VMASK16 convert_uchar16
#endif
#define FULL_CASE ((1 << NCORNERS) - 1)

// the case and new-edge mask of the point p of slab layer i0, f its user axes along which it is
// the last point (the scalar form of classify's lanes)
inline void classify_point(__global const uchar *sign, __global case_t *cases, __global vmask_t *vmask,
                           __global const int *counts, const int shared, const int s0, const int s1,
                           const int s2, const int s3, const int p, const int f, const int i0)
{
    // corners beyond the slab's last index take corner 0's sign: no crossing towards them
    const int v0 = sign[p];
    int c = 0;
#pragma unroll
    for (int v = 0; v < NCORNERS; ++v) {
        c |= ((v & f) == 0 ? (int)sign[p + corner_offset(v, s0, s1, s2, s3)] : v0) << v;
    }
    int m = 0;
#pragma unroll
    for (int j = 0; j < NDIRS; ++j) m |= (((c >> DIR_MASK(j)) ^ c) & 1) << j;
    // a crossed edge of the shared layer carries the vertex the slab below gave it (the slab
    // below used it: its top-layer cells hold the edge, and every case uses its crossed edges)
    if (i0 == 0) m &= ~shared;
    if (f != 0 || counts[c] == 0) c = 0;  // no cell here, or no simplex in it
    cases[p] = (case_t)c;
    vmask[p] = (vmask_t)m;
}

// 16 points of one row per work-item, as vectors (one point per work-item, as Intel's CPU
// runtime vectorised it, took twice as long); a row's last nx % 16 points go one at a time.
// A 3D range: (16-point groups of the last engine axis, the one before, the others together);
// no division per point. The sign buffer holds 16 bytes past its last point (read, unused, by
// the last point's lane).
__kernel __attribute__((vec_type_hint(int16))) void classify(
    __global const uchar *sign,      // (P + 16,) 1 where the value is positive
    __global case_t *cases,          // (P_pad,) out: case of the cell at its lowest corner, or 0
    __global vmask_t *vmask,         // (P_pad,) out: new crossed directions at this point
    __global const int *counts,      // (2^NCORNERS,) simplices per case
    int shared,                      // bit j: direction j lies in the layer shared with the
                                     // slab below (0 for the first slab)
    int s0, int s1, int s2, int s3,  // linear stride of user axis k
    int u0, int u1, int u2, int u3,  // user-axis bit of engine axis e
    int n0, int n1,                  // engine axis lengths (n1 only for DIM 4)
    int nx)                          // the last engine axis' length
{
    const int x0 = 16 * get_global_id(0);
    const int y = get_global_id(1);
    const int z = get_global_id(2);
    const int ny = get_global_size(1);
    const int p0 = (z * ny + y) * nx + x0;
    int f = 0, i0, u_x;  // f: user axes (but the row's) along which these points are the last
#if DIM == 2
    i0 = y;
    u_x = u1;
#elif DIM == 3
    i0 = z;
    u_x = u2;
    if (y == ny - 1) f |= u1;
#else
    i0 = z / n1;
    u_x = u3;
    if (y == ny - 1) f |= u2;
    if (z - i0 * n1 == n1 - 1) f |= u1;
#endif
    if (i0 == n0 - 1) f |= u0;
    if (x0 + 16 > nx) {
        for (int x = x0; x < nx; ++x)
            classify_point(sign, cases, vmask, counts, shared, s0, s1, s2, s3, p0 + x - x0,
                           f | (x == nx - 1 ? u_x : 0), i0);
        return;
    }
    // Most points lie away from the surface: when every loaded corner's signs equal the
    // point's own, each lane's case is empty or full and no edge is crossed. Testing that on
    // the bytes first skips the lanes' int arithmetic for most work-items (a lane that takes
    // corner 0's sign at the row's end only makes the test fail more often, never wrongly pass).
    {
        const uchar16 b0 = vload16(0, sign + p0);
        uchar16 x = (uchar16)(0);
#pragma unroll
        for (int v = 1; v < NCORNERS; ++v)
            if ((v & f) == 0) x |= vload16(0, sign + p0 + corner_offset(v, s0, s1, s2, s3)) ^ b0;
        if (!any(x != (uchar16)(0))) {
            vstore16(CONVERT_CASE16((int16)(0)), 0, cases + p0);
            vstore16(CONVERT_VMASK16((int16)(0)), 0, vmask + p0);
            return;
        }
    }
    // lane 15 is the row's last point when the row ends here
    const int16 lane = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    const int16 fv = (int16)(f) | select((int16)(0), (int16)(u_x), (lane == 15) & (int16)(x0 + 16 == nx ? -1 : 0));
    const int16 v0 = convert_int16(vload16(0, sign + p0));
    int16 c = (int16)(0);
#pragma unroll
    for (int v = 0; v < NCORNERS; ++v) {
        int16 s = v0;
        if ((v & f) == 0) {
            s = convert_int16(vload16(0, sign + p0 + corner_offset(v, s0, s1, s2, s3)));
            if (v & u_x) s = select(s, v0, (fv & (int16)(v)) != 0);
        }
        c |= s << v;
    }
    int16 m = (int16)(0);
#pragma unroll
    for (int j = 0; j < NDIRS; ++j) m |= (((c >> DIR_MASK(j)) ^ c) & 1) << j;
    if (i0 == 0) m &= (int16)(~shared);
    // no cell here, or no simplex in it: every case but the empty and the full one has a table
    // entry to look up, one lane at a time (rare: most points lie away from the surface)
    if (any((c != 0) & (c != FULL_CASE))) {
        int cs[16];
        vstore16(c, 0, cs);
        for (int l = 0; l < 16; ++l)
            if (counts[cs[l]] == 0) cs[l] = 0;
        c = vload16(0, cs);
    }
    c = select(c, (int16)(0), (fv != 0) | (c == FULL_CASE));
    vstore16(CONVERT_CASE16(c), 0, cases + p0);
    vstore16(CONVERT_VMASK16(m), 0, vmask + p0);
}

// FINITE(a, i): value i is neither NaN nor infinite (VFLOAT: the values are float or double)
#if VKIND == 1
#define FINITE(a, i) isfinite(vload_half((i), (a)))
#elif VKIND == 2
#define FINITE(a, i) (((a)[i] & 0x7ff0000000000000UL) != 0x7ff0000000000000UL)
#elif VFLOAT
#define FINITE(a, i) isfinite((a)[i])
#else
#define FINITE(a, i) 1
#endif

// 1 where the value is positive: mode 0 `v >= thr`, 1 `v <= thr`, 2 none (a level beyond an
// integer type's range)
inline uchar positive(const cmp_t v, const cmp_t thr, const int mode)
{
    return (uchar)(mode == 0 ? v >= thr : (mode == 1 ? v <= thr : 0));
}

// The same for 16 consecutive values at once: LOAD16_CMP(a, i) loads values 16 i .. 16 i + 15 as
// cmp16_t, BAD16(a, i) is a comparison's vector, true (-1) where a value is NaN or infinite.
// TRUTH16: a comparison's vector as bytes 1 / 0 (through char: Oclgrind's conversions of long
// vectors to uchar give 255 for 1).
#define TRUTH16(cmp) (as_uchar16(convert_char16(cmp)) & (uchar16)(1))
#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#if VKIND == 1
typedef float16 cmp16_t;
#define LOAD16_CMP(a, i) vload_half16((i), (a))
#define BAD16(a, i) (isfinite(vload_half16((i), (a))) == 0)
#elif VKIND == 2
typedef long16 cmp16_t;
inline long16 double_key16(const long16 b)
{
    return select(b ^ 0x7fffffffffffffffL, b, b >= (long16)(0));
}
#define LOAD16_CMP(a, i) double_key16(as_long16(vload16((i), (a))))
#define BAD16(a, i) ((vload16((i), (a)) & 0x7ff0000000000000UL) == 0x7ff0000000000000UL)
#else
typedef CAT(VTYPE, 16) cmp16_t;
#define LOAD16_CMP(a, i) vload16((i), (a))
#if VFLOAT
#define BAD16(a, i) (isfinite(vload16((i), (a))) == 0)
#else
#define BAD16(a, i) ((int16)(0))
#endif
#endif

// which side of the level each value lies on, 16 points per work-item (explicit vectors: one
// point per work-item ran 3-6x slower on Intel's CPU runtime, whose implicit vectoriser left the
// comparison and the byte stores scalar); the last work-item takes the n % 16 points left one at
// a time. bad[0] = 1 where a value is NaN or infinite (the host checks the values in this pass,
// not in one of its own; every work-item that finds one writes the same 1, which Oclgrind's race
// check accepts; an atomic made this pass about a tenth slower on Intel's CPU runtime).
// Comparing in classify instead, which reads 2^DIM corners per point, was no faster at 256^3 and
// slower in 4D, where the corners' values spread far more bytes through the caches than their
// signs.
__kernel __attribute__((vec_type_hint(float16))) void sign(__global const value_t *values, __global uchar *sign,
                                                           cmp_t thr, int mode, __global int *bad, int n)
{
    const int i = get_global_id(0);
    const int p0 = 16 * i;
    if (p0 + 16 <= n) {
        const cmp16_t v = LOAD16_CMP(values, i);
        const cmp16_t t = (cmp16_t)(thr);
        if (mode == 0)
            vstore16(TRUTH16(v >= t), i, sign);
        else if (mode == 1)
            vstore16(TRUTH16(v <= t), i, sign);
        else
            vstore16((uchar16)(0), i, sign);
        if (any(BAD16(values, i))) bad[0] = 1;
        return;
    }
    int b = 0;
    for (int p = p0; p < n; ++p) {
        sign[p] = positive(LOAD_CMP(values, p), thr, mode);
        b |= !FINITE(values, p);
    }
    if (b) bad[0] = 1;
}

__kernel CHUNK_KERNEL void count(__global const case_t *cases, __global const vmask_t *vmask,
                    __global const int *counts, __global int *chunk_vi, __global int *chunk_va,
                    __global int *chunk_s, __global int *chunk_a,
                    int in_plane)       // bit j: direction j lies in a layer
{
    const int g = get_global_id(0);
    const int base = g * CHUNK;
    int ni = 0, na_ = 0, ns = 0, na = 0;
    for (int i = base; i < base + CHUNK; i += 16) {
        if (!ZERO16(cases, i))
            FOR_NONZERO(cases, i, x) {
                ns += counts[cases[x]];
                ++na;
            }
        if (!ZERO16(vmask, i))
            FOR_NONZERO(vmask, i, x) {
                const int m = vmask[x];
                ni += popcount(m & in_plane);
                na_ += popcount(m & ~in_plane);
            }
    }
    chunk_vi[g] = ni;
    chunk_va[g] = na_;
    chunk_s[g] = ns;
    chunk_a[g] = na;
}

// exclusive scan in place of entries lo .. hi - 1 of four count arrays; their sums to sum[4]
inline void scan4(__global int *a0, __global int *a1, __global int *a2, __global int *a3,
                  const int lo, const int hi, int *sum)
{
    int s0 = 0, s1 = 0, s2 = 0, s3 = 0;
    for (int i = lo; i < hi; ++i) {
        const int v0 = a0[i], v1 = a1[i], v2 = a2[i], v3 = a3[i];
        a0[i] = s0;
        a1[i] = s1;
        a2[i] = s2;
        a3[i] = s3;
        s0 += v0;
        s1 += v1;
        s2 += v2;
        s3 += v3;
    }
    sum[0] = s0;
    sum[1] = s1;
    sum[2] = s2;
    sum[3] = s3;
}

// Exclusive scan of the four chunk count arrays, blocks of SCAN_BLOCK entries; block totals to
// blk (4 arrays of n_blocks, one after the other).
__kernel CHUNK_KERNEL void scan_chunks(__global int *chunk_vi, __global int *chunk_va,
                                       __global int *chunk_s, __global int *chunk_a,
                                       __global int *blk, int n_chunks, int n_blocks)
{
    const int b = get_global_id(0);
    const int lo = b * SCAN_BLOCK;
    int sum[4];
    scan4(chunk_vi, chunk_va, chunk_s, chunk_a, lo, min(lo + SCAN_BLOCK, n_chunks), sum);
    for (int k = 0; k < 4; ++k) blk[k * n_blocks + b] = sum[k];
}

__kernel void scan_blocks(__global int *blk, int n_blocks, __global int *totals)
{
    if (get_global_id(0) != 0) return;
    int sum[4];
    scan4(blk, blk + n_blocks, blk + 2 * n_blocks, blk + 3 * n_blocks, 0, n_blocks, sum);
    for (int k = 0; k < 4; ++k) totals[k] = sum[k];
}

// Per layer z (0 .. n0; n0: the slab's totals), the new in-plane and other vertices before its
// first point.
__kernel void layer_prefix(__global const vmask_t *vmask, __global const int *chunk_vi,
                           __global const int *chunk_va, __global const int *blk,
                           __global const int *totals, __global int *layer_in,
                           __global int *layer_ax, int layer, int n_points, int n_blocks,
                           int in_plane)
{
    const int z = get_global_id(0);
    const int q = z * layer;
    if (q >= n_points) {
        layer_in[z] = totals[0];
        layer_ax[z] = totals[1];
        return;
    }
    const int c = q / CHUNK;
    int vi = chunk_vi[c] + blk[c / SCAN_BLOCK];
    int va = chunk_va[c] + blk[n_blocks + c / SCAN_BLOCK];
    count_vertices(vmask, c * CHUNK, q, in_plane, &vi, &va);
    layer_in[z] = vi;
    layer_ax[z] = va;
}

// Layer z of the slab (z0: the slab's first layer in the grid) is a boundary of the numpy
// engine's slabs of `period` layers: its in-plane vertices come before its others.
#define BOUNDARY(z) ((z0 + (z)) > 0 && (z0 + (z)) % period == 0)
// bit 0: layer z is a boundary; bit 1: layer z + 1 is
#define FLAGS(z) (BOUNDARY(z) | (BOUNDARY((z) + 1) << 1))
// Follow consecutive points p upwards: z their layer, next the first point of the layer above,
// flags FLAGS(z) (no division per point)
#define TRACK(p, z, next, flags)          \
    while ((p) >= (next)) {               \
        ++(z);                            \
        (next) += layer;                  \
        (flags) = FLAGS(z);               \
    }

// New vertices numbered and their keys compacted; active cells compacted with their first
// simplex.
__kernel CHUNK_KERNEL void number(
    __global const case_t *cases, __global const vmask_t *vmask, __global const int *counts,
    __global const int *chunk_vi, __global const int *chunk_va,
    __global const int *chunk_s, __global const int *chunk_a,
    __global const int *blk,         // block prefixes of the four counts (scan_chunks)
    __global const int *layer_in, __global const int *layer_ax,  // layer_prefix
    __global int2 *vblock,           // VERTEX_BLOCKS: (P_pad / 16,) out, per block of 16 points
                                     // holding new vertices: the slab's new in-plane and other
                                     // vertices before the block (new_vertex)
    __global int *vfirst,            // else: (P,) out, index of the first new vertex at this
                                     // point (at a boundary: of its first in-plane one)
    __global int *vax,               // else: (P,) out, at a boundary: its first other one
    __global int *new_keys,          // (K,) out: point * NDIRS + direction, in index order
    __global int *carry_next,        // (layer * NDIRS,) out: the top layer's in-plane vertices
    __global int *act_p,             // (A,) out: point of each active cell
    __global int *act_s,             // (A,) out: its first simplex
    __global uchar *act_b,           // (A,) out: FLAGS of its layer
    int n_blocks, int v_base, int in_plane, int top_start, int layer, int z0, int period)
{
    const int g = get_global_id(0);
    const int gb = g / SCAN_BLOCK;
    int ki = chunk_vi[g] + blk[gb];
    int ka = chunk_va[g] + blk[n_blocks + gb];
    int s = chunk_s[g] + blk[2 * n_blocks + gb];
    int a = chunk_a[g] + blk[3 * n_blocks + gb];
    const int base = g * CHUNK;
    const int z_base = base / layer;
    int zc = z_base, nc = (z_base + 1) * layer, fc = FLAGS(z_base);  // cells' layer tracker
    int z = zc, nz = nc, fz = fc;                                  // vertices' layer tracker
    for (int i = base; i < base + CHUNK; i += 16) {
        if (!ZERO16(cases, i)) {
            FOR_NONZERO(cases, i, p) {
                const int c = cases[p];
                TRACK(p, zc, nc, fc);
                act_p[a] = p;
                act_s[a] = s;
                act_b[a] = (uchar)fc;
                ++a;
                s += counts[c];
            }
        }
        if (ZERO16(vmask, i)) continue;
#if VERTEX_BLOCKS
        vblock[i / 16] = (int2)(ki, ka);
#endif
        FOR_NONZERO(vmask, i, p) {
            const int m = vmask[p];
            TRACK(p, z, nz, fz);
            int bi, ba;  // next index of an in-plane and of another vertex here (see new_vertex)
            if (fz & 1) {
                bi = layer_ax[z] + ki;
                ba = layer_in[z + 1] + ka;
            } else {
                bi = ba = ki + ka;
            }
#if !VERTEX_BLOCKS
            vfirst[p] = v_base + bi;
            if (fz & 1) vax[p] = v_base + ba;
#endif
            const int keep = p >= top_start ? in_plane : 0;
            for (int j = 0; j < NDIRS; ++j) {
                if (!((m >> j) & 1)) continue;
                const int k = (!(fz & 1) || ((in_plane >> j) & 1)) ? bi++ : ba++;
                new_keys[k] = p * NDIRS + j;
                if ((keep >> j) & 1) carry_next[(p - top_start) * NDIRS + j] = v_base + k;
            }
            ki += popcount(m & in_plane);
            ka += popcount(m & ~in_plane);
        }
    }
}

// The slab's new in-plane (.x) and other (.y) vertices at the points of q's block of 16 that
// come before q: the popcounts of the block's masks below q's lane, read as 64-bit words (little-
// endian devices; others add lane by lane). With number's vblock this gives a vertex's index
// from its block, a 4 MB array at 256^3 that stays in the caches (new_vertex).
inline int2 lanes_before(__global const vmask_t *vmask, const int q, const int in_plane)
{
    const int b = q & ~15, l = q & 15;
    int ni = 0, na = 0;
#if defined(__ENDIAN_LITTLE__) && __ENDIAN_LITTLE__
    const int bits = LANE_BITS(vmask);
    const int per_word = 64 / bits;
    const ulong ip = (ulong)in_plane * (bits == 8 ? 0x0101010101010101UL : 0x0001000100010001UL);
    __global const ulong *w = (__global const ulong *)(vmask + b);
    const int full = l / per_word, part = l - full * per_word;
    for (int k = 0; k < full; ++k) {
        const ulong x = w[k];
        ni += (int)popcount(x & ip);
        na += (int)popcount(x & ~ip);
    }
    if (part) {
        const ulong x = w[full] & (((ulong)1 << (part * bits)) - 1);
        ni += (int)popcount(x & ip);
        na += (int)popcount(x & ~ip);
    }
#else
    count_vertices(vmask, b, q, in_plane, &ni, &na);
#endif
    return (int2)(ni, na);
}

// The index of the new vertex on the crossed edge (q, direction j; m = vmask[q]) of the active
// cell p, dir_step its edge_dir entry, bnd the cell's FLAGS. VERTEX_BLOCKS (2D and 3D): number's bi
// / ba at q from its block's bases and the masks before it (lanes_before), once per corner of
// the cell (kc, have); a per-point array of first indices made the 3D emit 1.3x slower (a
// line of a 67 MB array fetched per lookup at 256^3) but is faster in 4D, whose many simplices per
// cell reuse the lines and whose wider masks make lanes_before dearer (64^4: emit 108 against
// 165 ms).
inline int new_vertex(__global const vmask_t *vmask, __global const int2 *vblock,
                      __global const int *vfirst, __global const int *vax,
                      __global const int *layer_in, __global const int *layer_ax, const int p,
                      const int q, const int j, const int m, const int dir_step, const int bnd,
                      const int in_plane, const int layer, const int v_base, int2 *kc, uint *have)
{
    const int below = m & ((1 << j) - 1);
    const int step = (dir_step >> 8) & 0xff;
    const int boundary = (bnd >> step) & 1;
#if VERTEX_BLOCKS
    const int cn = dir_step >> 16;
    if (!((*have >> cn) & 1)) {
        kc[cn] = vblock[q >> 4] + lanes_before(vmask, q, in_plane);
        *have |= 1u << cn;
    }
    const int2 kq = kc[cn];
    if (!boundary) return v_base + kq.x + kq.y + popcount(below);
    const int z = p / layer + step;
    if ((in_plane >> j) & 1) return v_base + layer_ax[z] + kq.x + popcount(below & in_plane);
    return v_base + layer_in[z + 1] + kq.y + popcount(below & ~in_plane);
#else
    if (!boundary) return vfirst[q] + popcount(below);
    if ((in_plane >> j) & 1) return vfirst[q] + popcount(below & in_plane);
    return vax[q] + popcount(below & ~in_plane);
#endif
}

// One work-item per active cell: its simplices, table row by table row (out_t: int or long,
// the type of the final array).
#define EMIT_BODY(out)                                                                      \
    const int i = get_global_id(0);                                                         \
    const int p = act_p[i];                                                                 \
    const int bnd = act_b[i];                                                               \
    int s = act_s[i];                                                                       \
    const int c = cases[p];                                                                 \
    const int t1 = offsets[c + 1];                                                          \
    int2 kc[NCORNERS];  /* number's bi / ba at each corner, once looked up */               \
    uint have = 0;      /* bit v: kc[v] is set */                                           \
    for (int t = offsets[c]; t < t1; ++t, ++s) {                                            \
        for (int k = 0; k < DIM; ++k) {                                                     \
            const int e = table[t * DIM + k];                                               \
            const int q = p + edge_off[e];                                                  \
            const int j = edge_dir[e] & 0xff;                                               \
            const int m = vmask[q];                                                         \
            /* an edge of the shared layer not new here carries the slab below's vertex */ \
            out[s * DIM + k] = !((m >> j) & 1) ? carry[q * NDIRS + j]                       \
                : new_vertex(vmask, vblock, vfirst, vax, layer_in, layer_ax, p, q, j, m,    \
                             edge_dir[e], bnd, in_plane, layer, v_base, kc, &have);         \
        }                                                                                   \
    }

#define EMIT_ARGS                                                                           \
    __global const case_t *cases, __global const vmask_t *vmask,                            \
    __global const int2 *vblock,     /* number's block bases (VERTEX_BLOCKS) */             \
    __global const int *vfirst, __global const int *vax,  /* number's (otherwise) */        \
    __global const int *layer_in, __global const int *layer_ax,  /* layer_prefix */         \
    __global const int *carry, __global const int *act_p,                                   \
    __global const int *act_s, __global const uchar *act_b,                                 \
    __global const int *offsets,     /* (2^NCORNERS + 1,) first table row of each case */   \
    __global const uchar *table,     /* (M, DIM) edge ids */                                \
    __global const int *edge_off,    /* (E,) linear offset of edge e's lower corner */      \
    __global const int *edge_dir,    /* (E,) direction | layer step << 8 | corner << 16 */   \
    int in_plane, int layer, int v_base

// One cell per work-item, each with its own number of rows and scattered reads: compilers that
// vectorise across work-items (Intel's CPU runtime) run it 2-4x slower in lanes, so the hint
// says the kernel is vectorised already.
#define SCALAR_KERNEL __attribute__((vec_type_hint(int4)))
__kernel SCALAR_KERNEL void emit32(EMIT_ARGS, __global int *out) { EMIT_BODY(out) }
__kernel SCALAR_KERNEL void emit64(EMIT_ARGS, __global long *out) { EMIT_BODY(out) }

// One work-item per new vertex: its position, with cells.py's interpolate's operations in the
// same order (t = (level - f0) / (f1 - f0) clipped to [0, 1], NaN (the infinite padding of
// closed=True) taken as 1; origin + spacing * (index + t * bit)), so with FP64 the same bits.
__kernel void interpolate(
    __global const value_t *values, __global const int *keys, __global out_t *out,
    real_t level,
    int n1, int n2, int n3,          // engine axis lengths (1 beyond DIM)
    int s0, int s1, int s2, int s3,  // linear stride of user axis k
    int a0, int a1, int a2, int a3,  // user axis of engine axis e
    int b0, int b1, int b2, int b3,  // grid index of engine coordinate 0 along engine axis e
    real_t o0, real_t o1, real_t o2, real_t o3,   // origin along engine axis e
    real_t h0, real_t h1, real_t h2, real_t h3)   // spacing along engine axis e
{
    const int i = get_global_id(0);
    const int key = keys[i];
    const int p = key / NDIRS;
    const int mask = DIR_MASK(key - p * NDIRS);
    const int q = p + corner_offset(mask, s0, s1, s2, s3);
    const real_t f0 = LOAD_REAL(values, p);
    const real_t f1 = LOAD_REAL(values, q);
    real_t t = (level - f0) / (f1 - f0);
    t = isnan(t) ? (real_t)1 : fmin(fmax(t, (real_t)0), (real_t)1);
    int r = p, c[4];
#if DIM == 4
    c[3] = r % n3;
    r /= n3;
#endif
#if DIM >= 3
    c[2] = r % n2;
    r /= n2;
#endif
    c[1] = r % n1;
    c[0] = r / n1;
    const int ax[4] = {a0, a1, a2, a3};
    const int b[4] = {b0, b1, b2, b3};
    const real_t o[4] = {o0, o1, o2, o3};
    const real_t h[4] = {h0, h1, h2, h3};
#pragma unroll
    for (int e = 0; e < DIM; ++e) {
        real_t col = (real_t)(c[e] + b[e]);
        col = col + t * (real_t)((mask >> ax[e]) & 1);
        col = h[e] * col;
        STORE_REAL(out, i * DIM + ax[e], o[e] + col);
    }
}

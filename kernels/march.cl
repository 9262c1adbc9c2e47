// Marching extraction of one slab of grid layers (ao4d/cells_device.py drives it).
//
// The slab is a C-order engine grid of shape (n0, n1, ..., n_{DIM-1}); n0 = cell layers + 1.
// classify runs one work-item per point; the other passes one work-item per chunk of CHUNK
// consecutive points, walked in order 16 points at a time (a vector of 16 cases or masks that
// are all zero, most of the grid, is skipped at once). Per-chunk counts plus an exclusive scan
// over chunks give each point and cell its place in the output in the numpy engine's order
// (ao4d/cells.py):
//
//   classify    per point: the cell's case (bit v = corner v positive; 0 when no simplex) and
//               the bit mask of the crossed edges starting here that are new in this slab (not
//               carried from the slab below)
//   count       per chunk: simplices and new vertices
//   scan_chunks   exclusive scan of the chunk counts in blocks of SCAN_BLOCK chunks
//   scan_blocks exclusive scan of the block totals (one work-item; a few hundred blocks)
//   number      new vertices numbered in (point, direction) order, their keys compacted, the
//               top layer's in-plane vertices remembered for the next slab (carry)
//   emit        the simplices of every active cell, rows of the cell table in order, each edge
//               replaced by its vertex index
//
// A crossed edge (ends of different sign) inside the slab is used by every cell case that
// contains it (checked for every table by tests/test_cells_device.py), so "used" is read off the
// signs without marking. Work-group sizes are left to the runtime; no local memory; int only.
//
// Defines: DIM (2, 3, 4), NDIRS (edge directions of the table), CHUNK (a multiple of 16),
// SCAN_BLOCK.

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

// The 16 values at chunk position i are all zero.
inline int zero16_case(__global const case_t *a, int i)
{
#if DIM == 4
    ulong4 u = as_ulong4(vload16(0, a + i));
    return (u.s0 | u.s1 | u.s2 | u.s3) == 0;
#else
    ulong2 u = as_ulong2(vload16(0, a + i));
    return (u.s0 | u.s1) == 0;
#endif
}

inline int zero16_mask(__global const vmask_t *a, int i)
{
#if NDIRS > 8
    ulong4 u = as_ulong4(vload16(0, a + i));
    return (u.s0 | u.s1 | u.s2 | u.s3) == 0;
#else
    ulong2 u = as_ulong2(vload16(0, a + i));
    return (u.s0 | u.s1) == 0;
#endif
}

// Direction j's mask (cube corner): the cube table has the d axis directions, the Kuhn table
// every non-empty mask, both in increasing order (ao4d/cells.py's plan.dirs).
#if NDIRS == DIM
#define DIR_MASK(j) (1 << (j))
#else
#define DIR_MASK(j) ((j) + 1)
#endif

// A 3D range: (last engine axis, the one before, the others together); no division per point.
__kernel void classify(
    __global const uchar *sign,      // (P,) 1 where the value is positive
    __global case_t *cases,          // (P_pad,) out: case of the cell at its lowest corner, or 0
    __global vmask_t *vmask,         // (P_pad,) out: new crossed directions at this point
    __global const int *counts,      // (2^NCORNERS,) simplices per case
    int shared,                      // bit j: direction j lies in the layer shared with the
                                     // slab below (0 for the first slab)
    int s0, int s1, int s2, int s3,  // linear stride of user axis k
    int u0, int u1, int u2, int u3,  // user-axis bit of engine axis e
    int n0, int n1)                  // engine axis lengths (n1 only for DIM 4)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int z = get_global_id(2);
    const int nx = get_global_size(0), ny = get_global_size(1);
    const int p = (z * ny + y) * nx + x;
    int f = 0, i0;  // f: user axes along which this point is the last
#if DIM == 2
    i0 = y;
    if (x == nx - 1) f |= u1;
#elif DIM == 3
    i0 = z;
    if (x == nx - 1) f |= u2;
    if (y == ny - 1) f |= u1;
#else
    i0 = z / n1;
    if (x == nx - 1) f |= u3;
    if (y == ny - 1) f |= u2;
    if (z - i0 * n1 == n1 - 1) f |= u1;
#endif
    if (i0 == n0 - 1) f |= u0;
    // corners beyond the slab's last index take corner 0's sign: no crossing towards them
    const int v0 = sign[p];
    int c = 0;
#pragma unroll
    for (int v = 0; v < NCORNERS; ++v) {
        const int off = (v & 1) * s0 + ((v >> 1) & 1) * s1
#if DIM > 2
            + ((v >> 2) & 1) * s2
#endif
#if DIM > 3
            + ((v >> 3) & 1) * s3
#endif
            ;
        c |= ((v & f) == 0 ? (int)sign[p + off] : v0) << v;
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

__kernel CHUNK_KERNEL void count(__global const case_t *cases, __global const vmask_t *vmask,
                    __global const int *counts, __global int *chunk_v, __global int *chunk_s,
                    __global int *chunk_a)
{
    const int g = get_global_id(0);
    const int base = g * CHUNK;
    int nv = 0, ns = 0, na = 0;
    for (int i = base; i < base + CHUNK; i += 16) {
        if (!zero16_case(cases, i))
            for (int x = i; x < i + 16; ++x) {
                const int c = cases[x];
                ns += counts[c];
                na += c != 0;
            }
        if (!zero16_mask(vmask, i))
            for (int x = i; x < i + 16; ++x) nv += popcount((int)vmask[x]);
    }
    chunk_v[g] = nv;
    chunk_s[g] = ns;
    chunk_a[g] = na;
}

// exclusive scan in place of entries lo .. hi - 1 of three count arrays; their sums to sum[3]
inline void scan3(__global int *v_, __global int *s_, __global int *a_, const int lo, const int hi,
                  int *sum)
{
    int sv = 0, ss = 0, sa = 0;
    for (int i = lo; i < hi; ++i) {
        const int v = v_[i], s = s_[i], a = a_[i];
        v_[i] = sv;
        s_[i] = ss;
        a_[i] = sa;
        sv += v;
        ss += s;
        sa += a;
    }
    sum[0] = sv;
    sum[1] = ss;
    sum[2] = sa;
}

// Exclusive scan of three count arrays, blocks of SCAN_BLOCK entries; block totals to blk.
__kernel CHUNK_KERNEL void scan_chunks(__global int *chunk_v, __global int *chunk_s, __global int *chunk_a,
                          __global int *blk_v, __global int *blk_s, __global int *blk_a,
                          int n_chunks)
{
    const int b = get_global_id(0);
    const int lo = b * SCAN_BLOCK;
    int sum[3];
    scan3(chunk_v, chunk_s, chunk_a, lo, min(lo + SCAN_BLOCK, n_chunks), sum);
    blk_v[b] = sum[0];
    blk_s[b] = sum[1];
    blk_a[b] = sum[2];
}

__kernel void scan_blocks(__global int *blk_v, __global int *blk_s, __global int *blk_a,
                          int n_blocks, __global int *totals)
{
    if (get_global_id(0) != 0) return;
    int sum[3];
    scan3(blk_v, blk_s, blk_a, 0, n_blocks, sum);
    totals[0] = sum[0];
    totals[1] = sum[1];
    totals[2] = sum[2];
}

// New vertices numbered and their keys compacted; active cells compacted with their first
// simplex.
__kernel CHUNK_KERNEL void number(
    __global const case_t *cases, __global const vmask_t *vmask, __global const int *counts,
    __global const int *chunk_v, __global const int *blk_v,
    __global const int *chunk_s, __global const int *blk_s,
    __global const int *chunk_a, __global const int *blk_a,
    __global int *vfirst,            // (P,) out: index of the first new vertex at this point
    __global int *new_keys,          // (K,) out: point * NDIRS + direction, in index order
    __global int *carry_next,        // (layer * NDIRS,) out: the top layer's in-plane vertices
    __global int *act_p,             // (A,) out: point of each active cell
    __global int *act_s,             // (A,) out: its first simplex
    int v_base, int in_plane, int top_start)  // top_start: first point of the top layer
{
    const int g = get_global_id(0);
    int k = chunk_v[g] + blk_v[g / SCAN_BLOCK];
    int s = chunk_s[g] + blk_s[g / SCAN_BLOCK];
    int a = chunk_a[g] + blk_a[g / SCAN_BLOCK];
    const int base = g * CHUNK;
    for (int i = base; i < base + CHUNK; i += 16) {
        if (!zero16_case(cases, i)) {
            for (int p = i; p < i + 16; ++p) {
                const int c = cases[p];
                if (c == 0) continue;
                act_p[a] = p;
                act_s[a] = s;
                ++a;
                s += counts[c];
            }
        }
        if (zero16_mask(vmask, i)) continue;
        for (int p = i; p < i + 16; ++p) {
            const int m = vmask[p];
            if (m == 0) continue;
            vfirst[p] = v_base + k;
            const int keep = p >= top_start ? in_plane : 0;
            for (int j = 0; j < NDIRS; ++j) {
                if (!((m >> j) & 1)) continue;
                new_keys[k] = p * NDIRS + j;
                if ((keep >> j) & 1) carry_next[(p - top_start) * NDIRS + j] = v_base + k;
                ++k;
            }
        }
    }
}

// One work-item per active cell: its simplices, table row by table row.
__kernel void emit(
    __global const case_t *cases, __global const vmask_t *vmask, __global const int *vfirst,
    __global const int *carry, __global const int *act_p, __global const int *act_s,
    __global const int *offsets,     // (2^NCORNERS + 1,) first table row of each case
    __global const uchar *table,     // (M, DIM) edge ids
    __global const int *edge_off,    // (E,) linear offset of edge e's lower corner
    __global const int *edge_dir,    // (E,) direction index of edge e
    __global int *out)               // (S, DIM) out: vertex indices
{
    const int i = get_global_id(0);
    const int p = act_p[i];
    int s = act_s[i];
    const int c = cases[p];
    const int t1 = offsets[c + 1];
    for (int t = offsets[c]; t < t1; ++t, ++s) {
        for (int k = 0; k < DIM; ++k) {
            const int e = table[t * DIM + k];
            const int q = p + edge_off[e];
            const int j = edge_dir[e];
            const int m = vmask[q];
            out[s * DIM + k] = ((m >> j) & 1) ? vfirst[q] + popcount(m & ((1 << j) - 1))
                                              : carry[q * NDIRS + j];
        }
    }
}

// Exact voxel traversal (Amanatides-Woo) of the simulated sensor rays, one work-item per ray.
// Mirrors observe.traverse (numpy) operation by operation, in the same precision (REAL is
// double where the device supports it), so both mark the same cells.
// seen[cell] = 1 for every cell a ray enters at distance <= r_max, up to and including the
// first cell with stop[cell] != 0; leaving the grid ends the ray.
#pragma OPENCL FP_CONTRACT OFF
#ifdef USE_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double REAL;
#else
typedef float REAL;
#endif

__kernel void traverse(__global const uchar *stop, const int nx, const int ny, const int nz,
                       const REAL px, const REAL py, const REAL pz,
                       __global const REAL *directions, const int n_rays, const REAL r_max,
                       __global uchar *seen)
{
    const int ray = get_global_id(0);
    if (ray >= n_rays) {
        return;
    }
    const REAL p[3] = {px, py, pz};
    const int n[3] = {nx, ny, nz};
    int cell[3], step[3];
    REAL t_max[3], t_delta[3];
    for (int a = 0; a < 3; ++a) {
        const REAL d = directions[3 * ray + a];
        cell[a] = (int)floor(p[a]);
        step[a] = d > 0 ? 1 : -1;
        if (d != 0) {
            const REAL inv = (REAL)1 / d;
            t_max[a] = ((REAL)(cell[a] + (step[a] > 0)) - p[a]) * inv;
            t_delta[a] = fabs(inv);
        } else {
            t_max[a] = INFINITY;
            t_delta[a] = INFINITY;
        }
    }
    REAL t_enter = 0;
    for (;;) {
        if ((uint)cell[0] >= (uint)n[0] || (uint)cell[1] >= (uint)n[1] || (uint)cell[2] >= (uint)n[2] ||
            !(t_enter <= r_max)) {
            return;
        }
        const size_t flat = ((size_t)cell[0] * ny + cell[1]) * nz + cell[2];
        seen[flat] = 1;
        if (stop[flat]) {
            return;
        }
        const int axis = (t_max[0] <= t_max[1] && t_max[0] <= t_max[2]) ? 0 : (t_max[1] <= t_max[2] ? 1 : 2);
        t_enter = t_max[axis];
        cell[axis] += step[axis];
        t_max[axis] += t_delta[axis];
    }
}

// The same traversal, set up per ray (shared by the two kernels of the noisy observation).
#define TRAVERSAL_SETUP                                                            \
    const REAL p[3] = {px, py, pz};                                                \
    const int n[3] = {nx, ny, nz};                                                 \
    int cell[3], step[3];                                                          \
    REAL t_max[3], t_delta[3];                                                     \
    for (int a = 0; a < 3; ++a) {                                                  \
        const REAL d = directions[3 * ray + a];                                    \
        cell[a] = (int)floor(p[a]);                                                \
        step[a] = d > 0 ? 1 : -1;                                                  \
        if (d != 0) {                                                              \
            const REAL inv = (REAL)1 / d;                                          \
            t_max[a] = ((REAL)(cell[a] + (step[a] > 0)) - p[a]) * inv;             \
            t_delta[a] = fabs(inv);                                                \
        } else {                                                                   \
            t_max[a] = INFINITY;                                                   \
            t_delta[a] = INFINITY;                                                 \
        }                                                                          \
    }                                                                              \
    REAL t_enter = 0;

#define OUTSIDE (((uint)cell[0] >= (uint)n[0] || (uint)cell[1] >= (uint)n[1] || (uint)cell[2] >= (uint)n[2]))
#define FIRST_MIN_AXIS ((t_max[0] <= t_max[1] && t_max[0] <= t_max[2]) ? 0 : (t_max[1] <= t_max[2] ? 1 : 2))

// How each ray ends (observe.trace_rays' hit / depth / left_grid / hit_cell): status 1 = it
// stops at a stop cell entered within limit (depth = its entry distance, hit = its flat index),
// 2 = it leaves the grid within limit (depth = the distance where it leaves), 0 = neither.
__kernel void trace_end(__global const uchar *stop, const int nx, const int ny, const int nz,
                        const REAL px, const REAL py, const REAL pz,
                        __global const REAL *directions, const int n_rays, const REAL limit,
                        __global REAL *depth, __global int *status, __global long *hit)
{
    const int ray = get_global_id(0);
    if (ray >= n_rays) {
        return;
    }
    TRAVERSAL_SETUP
    depth[ray] = limit;
    status[ray] = 0;
    hit[ray] = -1;
    for (;;) {
        if (!(t_enter <= limit)) {
            return;
        }
        if (OUTSIDE) {
            depth[ray] = t_enter;
            status[ray] = 2;
            return;
        }
        const long flat = ((long)cell[0] * ny + cell[1]) * nz + cell[2];
        if (stop[flat]) {
            depth[ray] = t_enter;
            status[ray] = 1;
            hit[ray] = flat;
            return;
        }
        const int axis = FIRST_MIN_AXIS;
        t_enter = t_max[axis];
        cell[axis] += step[axis];
        t_max[axis] += t_delta[axis];
    }
}

// Labels of a measured ray (observe.measure_rays): empty[cell] = 1 for the cells the ray leaves
// at a distance <= measured[ray], occupied[cell] = 1 for the cell that contains the measured
// point; measured[ray] <= 0 = no return (nothing labelled). Rays pass through occupied cells.
__kernel void label_measured(const int nx, const int ny, const int nz,
                             const REAL px, const REAL py, const REAL pz,
                             __global const REAL *directions, const int n_rays,
                             __global const REAL *measured, __global uchar *empty,
                             __global uchar *occupied)
{
    const int ray = get_global_id(0);
    if (ray >= n_rays) {
        return;
    }
    const REAL m = measured[ray];
    if (!(m > 0)) {
        return;
    }
    TRAVERSAL_SETUP
    for (;;) {
        if (OUTSIDE || !(t_enter <= m)) {
            return;
        }
        const size_t flat = ((size_t)cell[0] * ny + cell[1]) * nz + cell[2];
        const REAL t_exit = fmin(fmin(t_max[0], t_max[1]), t_max[2]);
        if (t_exit <= m) {
            empty[flat] = 1;
        } else {
            occupied[flat] = 1;
            return;
        }
        const int axis = FIRST_MIN_AXIS;
        t_enter = t_max[axis];
        cell[axis] += step[axis];
        t_max[axis] += t_delta[axis];
    }
}

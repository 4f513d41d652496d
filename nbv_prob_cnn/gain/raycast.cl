// Probabilistic ray-casting gain (SPEC §4), one work-item per (origin, ray).
//
// The grid is one float per cell ("code"), C order [x][y][z] (2D grids have nz = 1):
//   code >= 0   unknown cell, occupancy probability p = code
//   code == -1  known empty (p = 0)
//   code == -2  known occupied (p = 1)
// Sample t of ray h from origin v is v + offsets[h][t] (precomputed round(t * b_h)).
// Cells outside the grid count as known occupied, so the ray stops there exactly.
#pragma OPENCL FP_CONTRACT OFF

#define MODE_PROBABILISTIC 0
#define MODE_INFORMATION_GAIN 1

__kernel void ray_gain(__global const float *code, const int nx, const int ny, const int nz,
                       __global const int *origins, const int n_origins,
                       __global const short *offsets, const int n_rays, const int n_samples,
                       const int nu, const float inv_total, const float eps,
                       const int mode, const float min_range,
                       __global float *out)
{
    const int gid = get_global_id(0);
    if (gid >= n_origins * n_rays) {
        return;
    }
    const int n = gid / n_rays;
    const int h = gid - n * n_rays;
    const int ox = origins[3 * n], oy = origins[3 * n + 1], oz = origins[3 * n + 2];
    __global const short *off = offsets + (size_t)h * n_samples * 3;
    float visible = 1.0f;  // Pr(r_t) = prod_{i<t} (1 - p_i)
    float hit = 0.0f;      // H(v, h)
    for (int t = 0; t < n_samples; ++t) {
        const int x = ox + off[3 * t], y = oy + off[3 * t + 1], z = oz + off[3 * t + 2];
        if ((uint)x >= (uint)nx || (uint)y >= (uint)ny || (uint)z >= (uint)nz) {
            break;
        }
        const float c = code[((size_t)x * ny + y) * nz + z];
        const float weight = (nu == 1) ? (float)t : (float)(t * t);
        if (mode == MODE_INFORMATION_GAIN) {
            if (c == -1.0f) {
                continue;
            }
            if (c >= 0.0f && (float)t >= min_range) {
                hit = weight;
            }
            break;
        }
        if (c >= 0.0f) {
            hit += visible * weight;
            visible *= 1.0f - c;
        } else if (c < -1.5f) {
            break;  // known occupied: Pr = 0 from here on
        }
        if (visible <= eps) {
            break;
        }
    }
    out[gid] = hit * inv_total;
}

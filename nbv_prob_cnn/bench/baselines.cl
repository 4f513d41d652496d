// Benchmark baselines only (nbv bench --suite planning); the planners never run these.
//
// baseline_ray_gain: the ray-gain kernel the planners used before the fused view_gain kernel
// (raycast.cl), kept verbatim apart from its name: one work-item per (origin, ray), per-ray
// gains stored to global memory, then summed into views on the host by a matrix product.
//
// naive_ray_gain: one work-item per (origin, ray) that marches a float position along the ray
// and stops at the first occupied cell (no precomputed offsets, a bounds check and a
// float-to-cell rounding per sample). It is NOT the authors' scheme: their probabilistic kernel
// never stops early and evaluates pow() per sample (authors_ray_gain below); naive is a simple
// float-marching kernel of our own, about 30x faster than theirs on a CPU.
//
// authors_ray_gain: our own kernel after the scheme of the authors' published code (written from
// its description, none of its source): one work-item per (origin, ray); a float position
// origin + t * bearing rounded to the nearest cell; every sample t = 0 .. n_samples - 1 marched
// (cells outside the grid count as empty, occluded rays keep marching); per sample the weight
// min(pow(t / focal, nu), 1) evaluated with pow(); hits and misses accumulated as the original
// kernel does (hits += w * seen * (1 - occluded), miss += w - that). Run with the original
// variant's range and weights (gain/variant.py) it gives the original variant's ray gains; the
// host sums hits and hits + miss per view (bench/planning.py).
//
// Grid code as in encode_grid: p >= 0 unknown, -1 known empty, -2 known occupied; unpadded.
#pragma OPENCL FP_CONTRACT OFF

#define MODE_PROBABILISTIC 0
#define MODE_INFORMATION_GAIN 1

__kernel void baseline_ray_gain(__global const float *code, const int nx, const int ny, const int nz,
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

__kernel void naive_ray_gain(__global const float *code, const int nx, const int ny, const int nz,
                             __global const float *origins, const int n_origins,
                             __global const float *directions, const int n_rays, const int n_samples,
                             const int nu, const float inv_total, __global float *out)
{
    const int gid = get_global_id(0);
    if (gid >= n_origins * n_rays) {
        return;
    }
    const int n = gid / n_rays;
    const int h = gid - n * n_rays;
    const float3 step = (float3)(directions[3 * h], directions[3 * h + 1], directions[3 * h + 2]);
    float3 position = (float3)(origins[3 * n], origins[3 * n + 1], origins[3 * n + 2]) + 0.5f;
    float visible = 1.0f;
    float hit = 0.0f;
    for (int t = 0; t < n_samples; ++t) {
        const int x = (int)floor(position.x), y = (int)floor(position.y), z = (int)floor(position.z);
        position += step;
        if (x < 0 || y < 0 || z < 0 || x >= nx || y >= ny || z >= nz) {
            break;
        }
        const float c = code[((size_t)x * ny + y) * nz + z];
        if (c < -1.5f) {
            break;  // first occupied cell
        }
        if (c >= 0.0f) {
            const float weight = (nu == 1) ? (float)t : (float)(t * t);
            hit += visible * weight;
            visible *= 1.0f - c;
        }
    }
    out[gid] = hit * inv_total;
}

// Hits and hits + miss per (origin, ray) after the authors' scheme (see the top of this file).
// free_hits: an unknown cell counts (1 - p) (the original's CNN and oracle maps), else 1 (P0 as
// an a-priori occlusion); either way it occludes with probability p.
__kernel void authors_ray_gain(__global const float *code, const int nx, const int ny, const int nz,
                               __global const float *origins, const int n_origins,
                               __global const float *directions, const int n_rays, const int n_samples,
                               const float nu, const float focal, const int free_hits,
                               __global float *hits, __global float *totals)
{
    const int gid = get_global_id(0);
    if (gid >= n_origins * n_rays) {
        return;
    }
    const int n = gid / n_rays;
    const int h = gid - n * n_rays;
    const float3 bearing = (float3)(directions[3 * h], directions[3 * h + 1], directions[3 * h + 2]);
    const float3 origin = (float3)(origins[3 * n], origins[3 * n + 1], origins[3 * n + 2]);
    float hit = 0.0f, miss = 0.0f, occluded = 0.0f;
    for (int t = 0; t < n_samples; ++t) {
        const float3 cell = floor(origin + bearing * (float)t + 0.5f);
        const int x = (int)cell.x, y = (int)cell.y, z = (int)cell.z;
        const float weight = min(pow((float)t / focal, nu), 1.0f);
        float seen = 0.0f, occluding = 0.0f;  // outside the grid and known empty: neither
        if (x >= 0 && y >= 0 && z >= 0 && x < nx && y < ny && z < nz) {
            const float c = code[((size_t)x * ny + y) * nz + z];
            if (c >= 0.0f) {
                seen = free_hits ? 1.0f - c : 1.0f;
                occluding = c;
            } else if (c < -1.5f) {
                occluding = 1.0f;
            }
        }
        const float reached = seen * (1.0f - occluded);
        hit += weight * reached;
        miss += weight * (1.0f - reached);
        occluded = 1.0f - (1.0f - occluded) * (1.0f - occluding);
    }
    hits[gid] = hit;
    totals[gid] = hit + miss;
}

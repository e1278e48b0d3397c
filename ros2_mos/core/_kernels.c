/* Fused per-point geometry kernels of ros2_mos (loaded with ctypes by ros2_mos/core/kernels.py).
 *
 * Each kernel does in one pass over the points what ros2_mos/core/projection.py and residuals.py do in
 * numpy as ~80 whole-array operations: rigid transform, spherical projection to a pixel, closest range
 * per pixel, residual or free-space value. The arithmetic is the numpy code's, in the same float32
 * operations and the same order (build with -ffp-contract=off: no fused multiply-adds), so that the
 * results are bit-identical; test/test_kernels.py checks that against the numpy functions. The
 * registration's sums, the connected regions of segments.py, the kNN vote of postprocess.py and autolabel's local
 * ground, voxel clusters, column rules and nearest-object attachment (offline/objects.py) are here too (the vote
 * uses GCC / Clang vector types; another compiler fails the optional build and numpy runs).
 *
 * Plain C with no Python or numpy headers: coordinates come as three float32 pointers with a common
 * stride (3 for (N, 3) rows, 1 for planes), so no copy is made to call a kernel.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

/* On x86-64 with GCC, the per-point arithmetic is also built for AVX2 and picked at load time (the same
 * operations, so the same results); elsewhere the compiler's baseline vectors serve. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define MOS_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define MOS_CLONES
#endif

/* Bumped whenever a signature changes: the loader refuses a stale build. */
#define MOS_KERNELS_ABI 13

int mos_kernels_abi(void) { return MOS_KERNELS_ABI; }

/* The projection's float32 constants, computed once in Python (projection.py's expressions). */
typedef struct {
    int32_t width;
    int32_t height;
    float u_scale;  /* -0.5 w / pi */
    float u_shift;  /* 0.5 w */
    float v_scale;  /* -h / fov */
    float v_shift;  /* h (1 + fov_down / fov) */
    float min_range;
    float max_range;
} MosSensor;

/* projection.py's _ATAN_COEFFS as float32, lowest order first. */
static const float ATAN_C[9] = {
    0.9999998863901668f, -0.333325970473658f, 0.19985906928451264f, -0.14161229789124125f,
    0.10498947063988592f, -0.07234857807645328f, 0.0397812161296372f, -0.014401347962729183f,
    0.0024567211130326477f,
};

/* projection.azimuth for one value: atan2(y, x) by octant reduction and the polynomial. Branch-free
 * (selects, not jumps), so that the loops below vectorise. */
static inline float azimuth(float x, float y) {
    float ax = fabsf(x), ay = fabsf(y);
    float big = ax > ay ? ax : ay;
    float small = ax < ay ? ax : ay;
    float t = big > 0.0f ? small / big : small;
    float t2 = t * t;
    float angle = ATAN_C[8];
    for (int k = 7; k >= 0; --k) {
        angle *= t2;
        angle += ATAN_C[k];
    }
    angle *= t;
    angle = ay > ax ? (float)(M_PI / 2) - angle : angle;
    angle = x < 0.0f ? (float)M_PI - angle : angle;
    return copysignf(angle, y);
}

/* Points per block: the transformed coordinates and pixels of a block stay in the L1 cache. */
#define BLOCK 256

/* residuals.transform_columns for a block: t is a row-major 3x4 float32 [R | t], or NULL (identity). */
static inline __attribute__((always_inline)) void transform_block(
    const float *restrict x, const float *restrict y, const float *restrict z, const int64_t stride, int64_t m,
    const float *restrict t, float *restrict ox, float *restrict oy, float *restrict oz) {
    if (!t) {
        for (int64_t i = 0; i < m; ++i) {
            ox[i] = x[i * stride];
            oy[i] = y[i * stride];
            oz[i] = z[i * stride];
        }
        return;
    }
    const float t00 = t[0], t01 = t[1], t02 = t[2], t03 = t[3];
    const float t10 = t[4], t11 = t[5], t12 = t[6], t13 = t[7];
    const float t20 = t[8], t21 = t[9], t22 = t[10], t23 = t[11];
    for (int64_t i = 0; i < m; ++i) {
        const float a = x[i * stride], b = y[i * stride], c = z[i * stride];
        float o = a * t00;
        o += b * t01;
        o += c * t02;
        o += t03;
        ox[i] = o;
        o = a * t10;
        o += b * t11;
        o += c * t12;
        o += t13;
        oy[i] = o;
        o = a * t20;
        o += b * t21;
        o += c * t22;
        o += t23;
        oz[i] = o;
    }
}

/* projection.pixel_index_columns for a block: column, row, range and whether the point lies inside. */
MOS_CLONES static void pixel_block(const float *restrict x, const float *restrict y, const float *restrict z, int64_t m,
                        const MosSensor *s, int32_t *restrict u, int32_t *restrict v, float *restrict range,
                        uint8_t *restrict inside) {
    const float u_scale = s->u_scale, u_shift = s->u_shift, v_scale = s->v_scale, v_shift = s->v_shift;
    const float height = (float)s->height, u_max = (float)(s->width - 1), v_max = (float)(s->height - 1);
    const float min_range = s->min_range, max_range = s->max_range;
    for (int64_t i = 0; i < m; ++i) {
        float rho = x[i] * x[i];
        rho += y[i] * y[i];
        float r = z[i] * z[i];
        r += rho;
        rho = sqrtf(rho);
        r = sqrtf(r);
        float v_f = azimuth(rho, z[i]);
        float u_f = azimuth(x[i], y[i]);
        u_f *= u_scale;
        u_f += u_shift;
        v_f *= v_scale;
        v_f += v_shift;
        inside[i] = (uint8_t)((v_f >= 0.0f) & (v_f < height) & (r > min_range) & (r < max_range));
        /* Clamping before the truncating cast, as np.clip(...).astype(np.int32). */
        float uc = u_f < 0.0f ? 0.0f : u_f;
        uc = uc > u_max ? u_max : uc;
        float vc = v_f < 0.0f ? 0.0f : v_f;
        vc = vc > v_max ? v_max : vc;
        u[i] = (int32_t)uc;
        v[i] = (int32_t)vc;
        range[i] = r;
    }
}

static inline __attribute__((always_inline)) void project_strided(
    const float *x, const float *y, const float *z, const int64_t stride, int64_t n, const float *t,
    const MosSensor *s, int32_t *u, int32_t *v, float *range, uint8_t *in_image, float *best, int32_t *winner) {
    float bx[BLOCK], by[BLOCK], bz[BLOCK], br[BLOCK];
    int32_t bu[BLOCK], bv[BLOCK];
    uint8_t bi[BLOCK];
    for (int64_t start = 0; start < n; start += BLOCK) {
        const int64_t m = n - start < BLOCK ? n - start : BLOCK;
        transform_block(x + start * stride, y + start * stride, z + start * stride, stride, m, t, bx, by, bz);
        int32_t *pu = u ? u + start : bu, *pv = v ? v + start : bv;
        float *pr = range ? range + start : br;
        uint8_t *pi = in_image ? in_image + start : bi;
        pixel_block(bx, by, bz, m, s, pu, pv, pr, pi);
        if (!best) continue;
        for (int64_t i = 0; i < m; ++i) {
            if (!pi[i]) continue;
            const int64_t p = (int64_t)pv[i] * s->width + pu[i];
            if (pr[i] <= best[p]) {
                best[p] = pr[i];
                if (winner) winner[p] = (int32_t)(start + i);
            }
        }
    }
}

/* Pixels of n points (transformed by t first, when given): pixel_index_columns(transform_columns(...)).
 * u, v, range, in_image may each be NULL. With best (H*W, filled with +inf) the closest range per pixel is
 * kept there, and with winner (H*W, filled with -1) the index of its point (the last one among equal
 * ranges): projection.closest_per_pixel. */
void mos_project(const float *x, const float *y, const float *z, int64_t stride, int64_t n, const float *t,
                 const MosSensor *s, int32_t *u, int32_t *v, float *range, uint8_t *in_image, float *best,
                 int32_t *winner) {
    if (stride == 3)
        project_strided(x, y, z, 3, n, t, s, u, v, range, in_image, best, winner);
    else if (stride == 1)
        project_strided(x, y, z, 1, n, t, s, u, v, range, in_image, best, winner);
    else
        project_strided(x, y, z, stride, n, t, s, u, v, range, in_image, best, winner);
}

/* The k (<= BLOCK) points at the flat pixels `pixels` of the planes x, y, z, moved by t and projected: their
 * coordinates (bx, by, bz), range, pixel and whether they lie inside. */
static inline void gathered_block(const float *x, const float *y, const float *z, const int64_t *pixels, int64_t k,
                                  const float *t, const MosSensor *s, float *bx, float *by, float *bz, float *range,
                                  int32_t *u, int32_t *v, uint8_t *inside) {
    float gx[BLOCK], gy[BLOCK], gz[BLOCK];
    for (int64_t i = 0; i < k; ++i) {
        const int64_t p = pixels[i];
        gx[i] = x[p];
        gy[i] = y[p];
        gz[i] = z[p];
    }
    transform_block(gx, gy, gz, 1, k, t, bx, by, bz);
    pixel_block(bx, by, bz, k, s, u, v, range, inside);
}

/* residuals.free_space_image over the flat pixels `occupied` (m of them) of an image whose points lie in
 * the planes x, y, z (H*W each): each point moved by t into the past scan's frame and compared with the
 * range the past scan measured there, (r_j(q) - |q|) / |q|, where both lie in (lo, hi); out (H*W) must be
 * zero-filled and keeps 0 elsewhere. */
void mos_free_space(const float *x, const float *y, const float *z, const int64_t *occupied, int64_t m,
                    const float *t, const MosSensor *s, const float *past_range, float lo, float hi, float *out) {
    float bx[BLOCK], by[BLOCK], bz[BLOCK], here[BLOCK];
    int32_t bu[BLOCK], bv[BLOCK];
    uint8_t inside[BLOCK];
    for (int64_t start = 0; start < m; start += BLOCK) {
        const int64_t k = m - start < BLOCK ? m - start : BLOCK;
        gathered_block(x, y, z, occupied + start, k, t, s, bx, by, bz, here, bu, bv, inside);
        for (int64_t i = 0; i < k; ++i) {
            if (!inside[i]) continue;
            float seen = past_range[(int64_t)bv[i] * s->width + bu[i]];
            const float r = here[i];
            if (r > lo && r < hi && seen > lo && seen < hi) {
                seen -= r;
                seen /= r;
                out[occupied[start + i]] = seen;
            }
        }
    }
}

/* The normal of the surface at each pixel of a scan's own points (planes px, py, pz; range 0 where empty):
 * the cross product of the vectors to the pixel on the right (wrapping around) and the one below, normalised,
 * where all three pixels hold points no farther apart than 5 % of the range + 0.3 m (squared distances
 * compared); (0, 0, 0) elsewhere and on the last row. Double precision, stored as float32
 * (core/registration.py, normal_planes). */
/* mos_normals for one pixel p0 with its right neighbour p1 and the one below p2. Branch-free, so that the
 * row loop vectorises. */
static inline void normal_at(const float *restrict px, const float *restrict py, const float *restrict pz,
                             const float *restrict range, int64_t p0, int64_t p1, int64_t p2, float *restrict nx_out,
                             float *restrict ny_out, float *restrict nz_out) {
    const double sx = px[p0], sy = py[p0], sz = pz[p0];
    const double ax = px[p1] - sx, ay = py[p1] - sy, az = pz[p1] - sz;
    const double cx = px[p2] - sx, cy = py[p2] - sy, cz = pz[p2] - sz;
    const double limit = 0.05 * (double)range[p0] + 0.3, limit2 = limit * limit;
    const double nx = ay * cz - az * cy, ny = az * cx - ax * cz, nz = ax * cy - ay * cx;
    const double nn = sqrt(nx * nx + ny * ny + nz * nz);
    const int ok = (range[p0] > 0.0f) & (range[p1] > 0.0f) & (range[p2] > 0.0f) &
                   (ax * ax + ay * ay + az * az < limit2) & (cx * cx + cy * cy + cz * cz < limit2) & (nn > 1e-9);
    const double div = ok ? nn : 1.0;
    nx_out[p0] = ok ? (float)(nx / div) : 0.0f;
    ny_out[p0] = ok ? (float)(ny / div) : 0.0f;
    nz_out[p0] = ok ? (float)(nz / div) : 0.0f;
}

MOS_CLONES void mos_normals(const float *restrict px, const float *restrict py, const float *restrict pz,
                            const float *restrict range, int32_t width, int32_t height, float *restrict nx_out,
                            float *restrict ny_out, float *restrict nz_out) {
    const int64_t w = width;
    for (int64_t v = 0; v + 1 < height; ++v) {
        const int64_t row = v * w;
        for (int64_t u = 0; u + 1 < w; ++u)
            normal_at(px, py, pz, range, row + u, row + u + 1, row + w + u, nx_out, ny_out, nz_out);
        normal_at(px, py, pz, range, row + w - 1, row, row + w + w - 1, nx_out, ny_out, nz_out);
    }
    for (int64_t u = (int64_t)(height - 1) * w; u < (int64_t)height * w; ++u) nx_out[u] = ny_out[u] = nz_out[u] = 0.0f;
}

/* The sums of one Gauss-Newton step of projective point-to-plane ICP (core/registration.py, plane_icp_sums):
 * each of the m current points at the flat pixels `points` of the planes x, y, z is moved by t into the past
 * scan's frame and paired with the past scan's own point at its pixel (planes px, py, pz) and that pixel's
 * normal (planes nx, ny, nz from mos_normals; zero: no pair). Pairs are kept where the point-to-plane distance
 * e is below plane_limit and the squared point distance below point_limit^2. With the Huber weight w(e) and
 * J = (n, q x n): hessian (6 x 6) += w J J^T, gradient (6) += w J e, cost += w e^2, in double precision.
 * Returns the number of pairs. */
int64_t mos_plane_icp_sums(const float *x, const float *y, const float *z, const int64_t *points, int64_t m,
                           const float *t, const MosSensor *s, const float *px, const float *py, const float *pz,
                           const float *nxp, const float *nyp, const float *nzp, float plane_limit,
                           float point_limit, float huber, double *hessian, double *gradient, double *cost) {
    const double point_limit2 = (double)point_limit * (double)point_limit;
    float bx[BLOCK], by[BLOCK], bz[BLOCK], br[BLOCK];
    int32_t bu[BLOCK], bv[BLOCK];
    uint8_t inside[BLOCK];
    const int64_t w = s->width;
    int64_t pairs = 0;
    /* Local sums (the upper triangle of the hessian): kept in registers, not re-read through the pointers. */
    double hs[21] = {0}, gs[6] = {0}, cs = 0.0;
    for (int64_t start = 0; start < m; start += BLOCK) {
        const int64_t k = m - start < BLOCK ? m - start : BLOCK;
        gathered_block(x, y, z, points + start, k, t, s, bx, by, bz, br, bu, bv, inside);
        for (int64_t i = 0; i < k; ++i) {
            if (!inside[i]) continue;
            const int64_t p0 = (int64_t)bv[i] * w + bu[i];
            const double nx = nxp[p0], ny = nyp[p0], nz = nzp[p0];
            if (nx == 0.0 && ny == 0.0 && nz == 0.0) continue;
            const double qx = bx[i], qy = by[i], qz = bz[i];
            const double dx = qx - px[p0], dy = qy - py[p0], dz = qz - pz[p0];
            const double e = nx * dx + ny * dy + nz * dz;
            if (!(fabs(e) < plane_limit && dx * dx + dy * dy + dz * dz < point_limit2)) continue;
            const double wt = fabs(e) <= huber ? 1.0 : huber / fabs(e);
            const double jac[6] = {nx, ny, nz, qy * nz - qz * ny, qz * nx - qx * nz, qx * ny - qy * nx};
            int idx = 0;
            for (int a = 0; a < 6; ++a) {
                const double wa = wt * jac[a];
                for (int b = a; b < 6; ++b) hs[idx++] += wa * jac[b];
                gs[a] += wa * e;
            }
            cs += wt * e * e;
            ++pairs;
        }
    }
    int idx = 0;
    for (int a = 0; a < 6; ++a) {
        for (int b = a; b < 6; ++b, ++idx) {
            hessian[6 * a + b] += hs[idx];
            if (b != a) hessian[6 * b + a] += hs[idx];
        }
        gradient[a] += gs[a];
    }
    *cost += cs;
    return pairs;
}

/* projection.project's images from mos_project's closest point per pixel: for each of the npix pixels, where
 * winner >= 0, the range (best), the winner's x, y, z (points: (N, 3) rows) and remission; 0 elsewhere
 * (point_index -1). range may alias best. */
void mos_fill_images(const int32_t *winner, const float *best, int64_t npix, const float *points,
                     const float *remission, float *range, float *x, float *y, float *z, float *rem_out,
                     int32_t *point_index) {
    for (int64_t p = 0; p < npix; ++p) {
        const int32_t i = winner[p];
        point_index[p] = i;
        if (i >= 0) {
            range[p] = best[p];
            x[p] = points[3 * (int64_t)i];
            y[p] = points[3 * (int64_t)i + 1];
            z[p] = points[3 * (int64_t)i + 2];
            rem_out[p] = remission[i];
        } else {
            range[p] = 0.0f;
            x[p] = y[p] = z[p] = rem_out[p] = 0.0f;
        }
    }
}

/* The closest range per pixel of n points moved by t (NULL: as they are), 0 where no point: projection.project_range
 * and residuals.past_range_image in one call. out has H*W entries. */
void mos_range_image(const float *x, const float *y, const float *z, int64_t stride, int64_t n, const float *t,
                     const MosSensor *s, float *out) {
    const int64_t npix = (int64_t)s->height * s->width;
    for (int64_t p = 0; p < npix; ++p) out[p] = INFINITY;
    mos_project(x, y, z, stride, n, t, s, NULL, NULL, NULL, NULL, out, NULL);
    for (int64_t p = 0; p < npix; ++p) out[p] = out[p] == INFINITY ? 0.0f : out[p];
}

/* Solves A x = b for a symmetric positive definite 6 x 6 A (row-major) by Cholesky; 0 when A is not. */
static int solve6(const double *a, const double *b, double *x) {
    double l[36] = {0}, y[6];
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j <= i; ++j) {
            double sum = a[6 * i + j];
            for (int k = 0; k < j; ++k) sum -= l[6 * i + k] * l[6 * j + k];
            if (i == j) {
                if (!(sum > 0.0)) return 0;
                l[6 * i + i] = sqrt(sum);
            } else {
                l[6 * i + j] = sum / l[6 * j + j];
            }
        }
    }
    for (int i = 0; i < 6; ++i) {
        double sum = b[i];
        for (int k = 0; k < i; ++k) sum -= l[6 * i + k] * y[k];
        y[i] = sum / l[6 * i + i];
    }
    for (int i = 5; i >= 0; --i) {
        double sum = y[i];
        for (int k = i + 1; k < 6; ++k) sum -= l[6 * k + i] * x[k];
        x[i] = sum / l[6 * i + i];
    }
    return 1;
}

/* registration.refine_to_past's Gauss-Newton loop: pose (row-major 4 x 4, current frame -> past frame) is
 * updated in place by up to `iterations` steps pose <- exp(delta) pose, delta = -(H + damping tr(H)/6 I)^-1 g from
 * mos_plane_icp_sums (exp: Rodrigues for the rotation, the translation as it is), stopping after a step smaller
 * than conv_t (m) and conv_r (rad). Returns the steps taken, or -1 (pose unspecified) when a step had fewer than
 * min_pairs pairs or its equations were singular. */
int32_t mos_refine(const float *x, const float *y, const float *z, const int64_t *points, int64_t m, double *pose,
                   const MosSensor *s, const float *px, const float *py, const float *pz, const float *nxp,
                   const float *nyp, const float *nzp, int32_t iterations, float plane_limit, float point_limit,
                   float huber, double damping, int64_t min_pairs, double conv_t, double conv_r) {
    int32_t step = 0;
    while (step < iterations) {
        float t[12];
        for (int i = 0; i < 12; ++i) t[i] = (float)pose[i];
        double h[36] = {0}, g[6] = {0}, cost = 0.0, delta[6], rhs[6];
        const int64_t pairs = mos_plane_icp_sums(x, y, z, points, m, t, s, px, py, pz, nxp, nyp, nzp, plane_limit,
                                                 point_limit, huber, h, g, &cost);
        if (pairs < min_pairs) return -1;
        const double trace = h[0] + h[7] + h[14] + h[21] + h[28] + h[35];
        for (int i = 0; i < 6; ++i) {
            h[7 * i] += damping * trace / 6.0;
            rhs[i] = -g[i];
        }
        if (!solve6(h, rhs, delta)) return -1;
        for (int i = 0; i < 6; ++i)
            if (!isfinite(delta[i])) return -1;
        const double angle = sqrt(delta[3] * delta[3] + delta[4] * delta[4] + delta[5] * delta[5]);
        double e[16] = {1, 0, 0, delta[0], 0, 1, 0, delta[1], 0, 0, 1, delta[2], 0, 0, 0, 1};
        if (angle > 0.0) {
            const double kx = delta[3] / angle, ky = delta[4] / angle, kz = delta[5] / angle;
            const double k[9] = {0, -kz, ky, kz, 0, -kx, -ky, kx, 0};
            const double sn = sin(angle), cs = 1.0 - cos(angle);
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) {
                    double kk = 0.0;
                    for (int q = 0; q < 3; ++q) kk += k[3 * i + q] * k[3 * q + j];
                    e[4 * i + j] = (i == j ? 1.0 : 0.0) + sn * k[3 * i + j] + cs * kk;
                }
        }
        double out[16];
        for (int i = 0; i < 4; ++i)
            for (int j = 0; j < 4; ++j) {
                double sum = 0.0;
                for (int q = 0; q < 4; ++q) sum += e[4 * i + q] * pose[4 * q + j];
                out[4 * i + j] = sum;
            }
        for (int i = 0; i < 16; ++i) pose[i] = out[i];
        ++step;
        const double moved = sqrt(delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2]);
        if (moved < conv_t && angle < conv_r) break;
    }
    return step;
}

/* residuals.residual_image of a current range image (npix pixels) against a past one: (r_j - r_0) / r_0
 * (its absolute value unless signed_), where both lie in (lo, hi); 0 elsewhere. */
void mos_residual(const float *current, const float *past, int64_t npix, float lo, float hi, int32_t signed_,
                  float *out) {
    for (int64_t p = 0; p < npix; ++p) {
        float r0 = current[p], rj = past[p];
        float d = 0.0f;
        if (r0 > lo && r0 < hi && rj > lo && rj < hi) {
            d = (rj - r0) / r0;
            if (!signed_) d = fabsf(d);
        }
        out[p] = d;
    }
}

/* segments.connected_regions: connected components of the valid pixels of an h x w image, 4-neighbours (wrapping
 * in azimuth) linked where |r_a - r_b| < max(min_jump, rel * min(r_a, r_b)). Union-find that always hooks the
 * larger root onto the smaller, so that each pixel's label is the smallest pixel id of its region, as the numpy
 * code's; -1 where not valid. */
static inline int64_t find_root(int64_t *parent, int64_t i) {
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

static inline void join(int64_t *parent, int64_t a, int64_t b) {
    a = find_root(parent, a);
    b = find_root(parent, b);
    if (a < b) parent[b] = a;
    else if (b < a) parent[a] = b;
}

static inline int close_ranges(float a, float b, float rel, float min_jump) {
    const float limit = rel * fminf(a, b);
    return fabsf(a - b) < fmaxf(min_jump, limit);
}

void mos_connected_regions(const uint8_t *valid, const float *range, int32_t h, int32_t w, float rel, float min_jump,
                           int64_t *labels) {
    const int64_t npix = (int64_t)h * w;
    for (int64_t p = 0; p < npix; ++p) labels[p] = p;
    for (int32_t row = 0; row < h; ++row) {
        for (int32_t col = 0; col < w; ++col) {
            const int64_t p = (int64_t)row * w + col;
            if (!valid[p]) continue;
            const int64_t right = (int64_t)row * w + (col + 1 == w ? 0 : col + 1);
            if (valid[right] && close_ranges(range[p], range[right], rel, min_jump)) join(labels, p, right);
            if (row + 1 < h && valid[p + w] && close_ranges(range[p], range[p + w], rel, min_jump))
                join(labels, p, p + w);
        }
    }
    for (int64_t p = 0; p < npix; ++p) labels[p] = valid[p] ? find_root(labels, p) : -1;
}

/* objects.voxel_clusters: the connected components of the occupied voxels `cells` (n keys, sorted, unique), two
 * cells joined where one's key plus one of the `m` positive `steps` is the other's (the neighbour offsets as keys).
 * cluster[i] is the component's index, components numbered by their smallest cell, as np.unique over the numpy
 * code's roots numbers them. A cursor per step walks the sorted keys once: O(m n). parent is scratch of n. */
void mos_voxel_clusters(const int64_t *cells, int64_t n, const int64_t *steps, int32_t m, int64_t *parent,
                        int64_t *cursor, int64_t *cluster) {
    for (int64_t i = 0; i < n; ++i) parent[i] = i;
    for (int32_t s = 0; s < m; ++s) cursor[s] = 0;
    for (int64_t i = 0; i < n; ++i) {
        for (int32_t s = 0; s < m; ++s) {
            const int64_t want = cells[i] + steps[s];
            int64_t j = cursor[s];
            if (j <= i) j = i + 1;
            while (j < n && cells[j] < want) ++j;
            cursor[s] = j;
            if (j < n && cells[j] == want) join(parent, i, j);
        }
    }
    int64_t next = 0;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t root = find_root(parent, i);
        cluster[i] = root == i ? next++ : cluster[root];
    }
}

/* objects._next_return: the first return in column c from row v + step on (up to `search` rows), -1 where none. */
static inline int32_t next_return(const int32_t *image, int32_t h, int32_t w, int32_t v, int32_t c, int32_t step,
                                  int32_t search) {
    for (int32_t k = 1; k <= search; ++k) {
        const int32_t row = v + step * k;
        if (row < 0 || row >= h) break;
        const int32_t p = image[(int64_t)row * w + c];
        if (p >= 0) return p;
    }
    return -1;
}

/* objects.attach_below over the h x w image of closest points (-1 empty), row by row from the top: a point
 * `chosen` takes the object of the next return above it where that is on one, rises over it at least `steep`
 * times their horizontal distance apart, and the point does not continue the ground of the return below it. The
 * numpy code's arithmetic: float32 differences, the two slopes in double, the ground step in float32. With
 * under > 0, a point lower than that return and behind it by at most `under` (horizontally) joins whatever the
 * slope and the ground below (only where under_ok[p], if under_ok is not NULL). A row's points read only rows
 * above it, so one pass in place equals the numpy code's row-at-a-time update. */
void mos_attach_below(const int32_t *image, int32_t h, int32_t w, const uint8_t *chosen, const float *horizontal,
                      const float *z, double steep, double gentle, float ground_step, int32_t search,
                      float under, const uint8_t *under_ok, int32_t *point_object, uint8_t *attached) {
    for (int32_t v = 1; v < h; ++v) {
        for (int32_t c = 0; c < w; ++c) {
            const int32_t p = image[(int64_t)v * w + c];
            if (p < 0 || !chosen[p]) continue;
            const int32_t a = next_return(image, h, w, v, c, -1, search);
            if (a < 0 || point_object[a] < 0) continue;
            const float rise = z[a] - z[p], behind = horizontal[p] - horizontal[a];
            if (!(rise > 0.0f)) continue;
            if (under > 0.0f && behind > 0.0f && behind <= under && (!under_ok || under_ok[p])) {  /* under the face */
                point_object[p] = point_object[a];
                attached[p] = 1;
                continue;
            }
            if (!((double)rise >= steep * (double)fabsf(behind))) continue;
            const int32_t b = next_return(image, h, w, v, c, 1, search);
            const int32_t bb = b < 0 ? 0 : b;
            const float step = z[p] - z[bb], apart = fabsf(horizontal[p] - horizontal[bb]);
            const double limit = fmin((double)ground_step, gentle * (double)apart);
            if (b >= 0 && (double)step <= limit) continue;  /* the ground at the object's foot */
            point_object[p] = point_object[a];
            attached[p] = 1;
        }
    }
}

/* objects.attach_over, row by row from the bottom: a point `chosen` takes the object of the next return below it
 * where that is on one and the point rises over it at least `steep` times their horizontal distance apart and at
 * most `row_slope` times its own horizontal range. */
void mos_attach_over(const int32_t *image, int32_t h, int32_t w, const uint8_t *chosen, const float *horizontal,
                     const float *z, double steep, double row_slope, int32_t search, int32_t *point_object,
                     uint8_t *attached) {
    for (int32_t v = h - 2; v >= 0; --v) {
        for (int32_t c = 0; c < w; ++c) {
            const int32_t p = image[(int64_t)v * w + c];
            if (p < 0 || !chosen[p]) continue;
            const int32_t b = next_return(image, h, w, v, c, 1, search);
            if (b < 0 || point_object[b] < 0) continue;
            const float rise = z[p] - z[b];
            if (rise > 0.0f && (double)rise >= steep * (double)fabsf(horizontal[p] - horizontal[b])
                && (double)rise <= row_slope * (double)horizontal[p]) {
                point_object[p] = point_object[b];
                attached[p] = 1;
            }
        }
    }
}

/* objects.local_ground's window over a rows x cols grid: per cell the smallest of the (2 radius + 1)^2 cells around
 * it (+inf outside the grid), by rows then columns (the minimum is exact in any order). tmp: rows * cols floats. */
static void window_min(const float *grid, int32_t rows, int32_t cols, int32_t radius, float *tmp, float *out) {
    for (int32_t i = 0; i < rows; ++i) {
        for (int32_t j = 0; j < cols; ++j) {
            float m = INFINITY;
            const int32_t j0 = j - radius < 0 ? 0 : j - radius, j1 = j + radius >= cols ? cols - 1 : j + radius;
            for (int32_t jj = j0; jj <= j1; ++jj) m = fminf(m, grid[(int64_t)i * cols + jj]);
            tmp[(int64_t)i * cols + j] = m;
        }
    }
    for (int32_t i = 0; i < rows; ++i) {
        const int32_t i0 = i - radius < 0 ? 0 : i - radius, i1 = i + radius >= rows ? rows - 1 : i + radius;
        for (int32_t j = 0; j < cols; ++j) {
            float m = INFINITY;
            for (int32_t ii = i0; ii <= i1; ++ii) m = fminf(m, tmp[(int64_t)ii * cols + j]);
            out[(int64_t)i * cols + j] = m;
        }
    }
}

/* objects.local_ground for n points (x, y, z with a common stride) whose cells (floor(x / cell), floor(y / cell),
 * float32 as the numpy code) were moved to start at 0 and span rows x cols: per point the lowest point within
 * radius cells of its own, leaving out (where use_drop) points more than `drop` below the lower quartile of their
 * cell's window of cells' lowest points (the finite ones sorted, element (filled - 1) / 4). cell_of: n int64
 * (the points' flat cells, given), grid: 3 * rows * cols floats of scratch, window: (2 radius + 1)^2 floats. */
void mos_local_ground(const float *z, int64_t stride, int64_t n, const int64_t *cell_of, int32_t rows, int32_t cols,
                      int32_t radius, int32_t use_drop, float drop, float *grid, float *window, float *out) {
    const int64_t ncells = (int64_t)rows * cols;
    float *lowest = grid, *tmp = grid + ncells, *ground = grid + 2 * ncells;
    for (int64_t c = 0; c < ncells; ++c) lowest[c] = INFINITY;
    for (int64_t p = 0; p < n; ++p) lowest[cell_of[p]] = fminf(lowest[cell_of[p]], z[p * stride]);
    int64_t dropped = 0;
    if (use_drop) {
        /* ground[] holds each occupied cell's quartile minus drop for now */
        for (int64_t c = 0; c < ncells; ++c) ground[c] = NAN;
        for (int64_t p = 0; p < n; ++p) {
            const int64_t c = cell_of[p];
            if (ground[c] != ground[c]) {
                const int32_t i = (int32_t)(c / cols), j = (int32_t)(c % cols);
                int32_t filled = 0;
                for (int32_t ii = i - radius; ii <= i + radius; ++ii) {
                    if (ii < 0 || ii >= rows) continue;
                    for (int32_t jj = j - radius; jj <= j + radius; ++jj) {
                        if (jj < 0 || jj >= cols) continue;
                        const float v = lowest[(int64_t)ii * cols + jj];
                        if (v < INFINITY) {  /* insertion sort of the finite values */
                            int32_t k = filled++;
                            while (k > 0 && window[k - 1] > v) {
                                window[k] = window[k - 1];
                                --k;
                            }
                            window[k] = v;
                        }
                    }
                }
                ground[c] = window[(filled > 0 ? filled - 1 : 0) / 4] - drop;
            }
            if (!(z[p * stride] >= ground[c])) ++dropped;
        }
        if (dropped) {  /* the cells' lowest points again, without the dropped ones */
            float *kept_lowest = tmp;
            for (int64_t c = 0; c < ncells; ++c) kept_lowest[c] = INFINITY;
            for (int64_t p = 0; p < n; ++p) {
                const int64_t c = cell_of[p];
                if (z[p * stride] >= ground[c]) kept_lowest[c] = fminf(kept_lowest[c], z[p * stride]);
            }
            memcpy(lowest, kept_lowest, (size_t)ncells * sizeof(float));
        }
    }
    window_min(lowest, rows, cols, radius, tmp, ground);
    for (int64_t p = 0; p < n; ++p) out[p] = ground[cell_of[p]];
}

/* objects._cell_keys for one cell: clipped to +-(2^20 - 1), moved to be positive and packed. */
#define MOS_CELL_OFFSET ((int64_t)1 << 20)
#define MOS_CELL_SPAN ((int64_t)1 << 21)
static inline int64_t cell_key(int64_t i, int64_t j) {
    i = i < 1 - MOS_CELL_OFFSET ? 1 - MOS_CELL_OFFSET : (i > MOS_CELL_OFFSET - 1 ? MOS_CELL_OFFSET - 1 : i);
    j = j < 1 - MOS_CELL_OFFSET ? 1 - MOS_CELL_OFFSET : (j > MOS_CELL_OFFSET - 1 ? MOS_CELL_OFFSET - 1 : j);
    return (i + MOS_CELL_OFFSET) * MOS_CELL_SPAN + (j + MOS_CELL_OFFSET);
}

/* The first index of the sorted keys[0..n) whose key is at least `key` (n where none). */
static inline int64_t lower_bound(const int64_t *keys, int64_t n, int64_t key) {
    int64_t lo = 0, hi = n;
    while (lo < hi) {
        const int64_t mid = lo + (hi - lo) / 2;
        if (keys[mid] < key) lo = mid + 1;
        else hi = mid;
    }
    return lo;
}

/* The index of key in the sorted keys[0..n), -1 where absent. */
static inline int64_t find_key(const int64_t *keys, int64_t n, int64_t key) {
    const int64_t at = lower_bound(keys, n, key);
    return at < n && keys[at] == key ? at : -1;
}

/* objects.attach_to_nearest after its object cells: each of the m points `loose` (indices into x, y with a common
 * stride) whose `reach`-sized cell is one of, or beside one of, the objects' `reach`-sized cells `near` (sorted
 * keys) takes the owner of the first of the `s` (di, dj) `steps` (nearest first) from its `grid`-sized cell that is
 * one of the objects' `grid`-sized cells `cells` (sorted keys, `owner` each). Cells as the numpy code's: the float32
 * quotient's floor, keys by cell_key. */
void mos_attach_nearest(const float *x, const float *y, int64_t stride, const int64_t *loose, int64_t m,
                        const int64_t *near, int64_t nnear, float reach, const int64_t *cells, const int32_t *owner,
                        int64_t ncells, float grid, const int64_t *steps, int32_t s, int32_t *point_object,
                        uint8_t *attached) {
    for (int64_t t = 0; t < m; ++t) {
        const int64_t p = loose[t];
        const float px = x[p * stride], py = y[p * stride];
        const int64_t key = cell_key((int64_t)floorf(px / reach), (int64_t)floorf(py / reach));
        int beside = 0;
        for (int64_t di = -1; di <= 1 && !beside; ++di) {  /* a key in [key - 1, key + 1] on rows di */
            const int64_t row = key + di * MOS_CELL_SPAN, at = lower_bound(near, nnear, row - 1);
            beside = at < nnear && near[at] <= row + 1;
        }
        if (!beside) continue;
        const int64_t i = (int64_t)floorf(px / grid), j = (int64_t)floorf(py / grid);
        for (int32_t k = 0; k < s; ++k) {
            const int64_t at = find_key(cells, ncells, cell_key(i + steps[2 * k], j + steps[2 * k + 1]));
            if (at >= 0) {
                point_object[p] = owner[at];
                attached[p] = 1;
                break;
            }
        }
    }
}

/* segments.grow_regions: out[p] = 1 where p's region (labels[p] >= 0, a pixel id as mos_connected_regions gives)
 * holds seeds on at least `fraction` of its pixels (and on one at least). count is scratch of 2 * npix int32. */
void mos_grow_regions(const int64_t *labels, const uint8_t *seeds, int64_t npix, double fraction, int32_t *count,
                      uint8_t *out) {
    int32_t *size = count, *hits = count + npix;
    for (int64_t p = 0; p < npix; ++p) size[p] = hits[p] = 0;
    for (int64_t p = 0; p < npix; ++p) {
        const int64_t l = labels[p];
        if (l < 0) continue;
        size[l] += 1;
        hits[l] += seeds[p] != 0;
    }
    for (int64_t p = 0; p < npix; ++p) {
        const int64_t l = labels[p];
        out[p] = l >= 0 && hits[l] > 0 && (double)hits[l] >= fraction * (double)size[l];
    }
}

/* postprocess._window_mixed: mixed[p] = 1 where the window x window pixels around p (rows clipped, columns
 * wrapping) hold probabilities on both sides of threshold. Separable: "any below" / "any above" along the columns,
 * then along the rows. scratch: 2 * h * w bytes. */
static void window_mixed(const float *prob, int32_t h, int32_t w, int32_t half, float threshold, uint8_t *scratch,
                         uint8_t *mixed) {
    const int64_t npix = (int64_t)h * w;
    uint8_t *below = scratch, *above = scratch + npix;
    for (int32_t r = 0; r < h; ++r) {
        const float *row = prob + (int64_t)r * w;
        for (int32_t c = 0; c < w; ++c) {
            uint8_t b = 0, a = 0;
            for (int32_t d = -half; d <= half; ++d) {
                int32_t cc = c + d;
                cc = cc < 0 ? cc + w : (cc >= w ? cc - w : cc);
                const uint8_t is_below = row[cc] < threshold;
                b |= is_below;
                a |= !is_below;
            }
            below[(int64_t)r * w + c] = b;
            above[(int64_t)r * w + c] = a;
        }
    }
    for (int32_t r = 0; r < h; ++r) {
        const int32_t r0 = r - half < 0 ? 0 : r - half, r1 = r + half >= h ? h - 1 : r + half;
        for (int32_t c = 0; c < w; ++c) {
            uint8_t b = 0, a = 0;
            for (int32_t rr = r0; rr <= r1; ++rr) {
                b |= below[(int64_t)rr * w + c];
                a |= above[(int64_t)rr * w + c];
            }
            mixed[(int64_t)r * w + c] = b & a;
        }
    }
}

/* Range given to empty and padded pixels: far beyond any cut-off, so they never vote (postprocess._EMPTY_RANGE). */
#define MOS_EMPTY_RANGE 1e9f
#define MOS_LANES 8
/* MOS_LANES floats, and a lane mask, as GCC / Clang vector types (SSE, AVX or NEON registers, or scalars). */
typedef float mos_lanes __attribute__((vector_size(4 * MOS_LANES)));
typedef int32_t mos_mask __attribute__((vector_size(4 * MOS_LANES)));

/* Lane by lane: a where mask, else b (bit operations: the same in every lane, no branch). A macro, not a
 * function: vector arguments would change the calling convention with the instruction set. */
#define SELECT_LANES(mask, a, b) ((mos_lanes)(((mask) & (mos_mask)(a)) | (~(mask) & (mos_mask)(b))))

/* The window of the point at (pu, pv), range own: each cell's distance (range difference times its weight) and
 * probability, into lane `lane` of the batch arrays. */
static inline void knn_window(const float *prob, const float *range, int32_t h, int32_t w, int32_t pu, int32_t pv,
                              float own, int32_t half, int32_t window, const float *weights,
                              float (*dist)[MOS_LANES], float (*probs)[MOS_LANES], int32_t lane) {
    int32_t j = 0;
    if (pv >= half && pv + half < h && pu >= half && pu + half < w) {  /* inside: no padding, no wrap */
        for (int32_t dr = -half; dr <= half; ++dr) {
            const int64_t row = (int64_t)(pv + dr) * w + pu - half;
            for (int32_t dc = 0; dc < window; ++dc, ++j) {
                const float here = range[row + dc];
                const float rr = here > 0.0f ? here : MOS_EMPTY_RANGE;
                dist[j][lane] = fabsf(rr - own) * weights[j];
                probs[j][lane] = prob[row + dc];
            }
        }
        return;
    }
    for (int32_t dr = -half; dr <= half; ++dr) {
        const int32_t r = pv + dr;
        for (int32_t dc = -half; dc <= half; ++dc, ++j) {
            int32_t c = pu + dc;
            c = c < 0 ? c + w : (c >= w ? c - w : c);
            float rr = MOS_EMPTY_RANGE, p = 0.0f;
            if (r >= 0 && r < h) {
                const float here = range[(int64_t)r * w + c];
                rr = here > 0.0f ? here : MOS_EMPTY_RANGE;
                p = prob[(int64_t)r * w + c];
            }
            dist[j][lane] = fabsf(rr - own) * weights[j];
            probs[j][lane] = p;
        }
    }
}

/* postprocess.knn_backproject for n points at pixels (u, v) with ranges prange: each point's moving probability
 * by the kNN vote over the window x window pixels around its own (rows padded with empty pixels, columns
 * wrapping), the float32 arithmetic of the numpy code (sums in another order: equal to ~1e-7). With use_threshold,
 * a point whose window holds no probability on one side of threshold keeps its own pixel's probability (the vote
 * could not change its label). weights: the window's inverse Gaussian, window * window floats; scratch: 3 * h * w
 * bytes (with use_threshold). The votes run MOS_LANES points at a time: the k smallest distances of each lane
 * sink through a min/max chain, the same operations in every lane (vectors, and no data-dependent branch). */
MOS_CLONES void mos_knn_vote(const float *prob, const float *range, int32_t h, int32_t w, const int32_t *u,
                             const int32_t *v, const float *prange, int64_t n, int32_t window, int32_t k,
                             const float *weights, float cutoff, float threshold, int32_t use_threshold,
                             uint8_t *scratch, float *out) {
    const int32_t half = window / 2, cells = window * window, center = cells / 2;
    float dist[225][MOS_LANES], probs[225][MOS_LANES];
    mos_lanes smallest[225];
    int64_t batch[MOS_LANES];
    int32_t filled = 0;
    uint8_t *mixed = NULL;
    if (use_threshold) {
        mixed = scratch + 2 * (int64_t)h * w;
        window_mixed(prob, h, w, half, threshold, scratch, mixed);
    }
    for (int64_t i = 0; i <= n; ++i) {
        if (i < n) {
            const int32_t pu = u[i], pv = v[i];
            if (mixed != NULL && !mixed[(int64_t)pv * w + pu]) {
                out[i] = prob[(int64_t)pv * w + pu];
                continue;
            }
            knn_window(prob, range, h, w, pu, pv, prange[i], half, window, weights, dist, probs, filled);
            dist[center][filled] = -1.0f;
            batch[filled++] = i;
            if (filled < MOS_LANES) continue;
        } else if (filled == 0) {
            break;
        }
        for (int32_t lane = filled; lane < MOS_LANES; ++lane) {  /* a last, partial batch: idle lanes */
            for (int32_t a = 0; a < cells; ++a) dist[a][lane] = probs[a][lane] = 0.0f;
        }
        const mos_lanes zero = {0}, one = zero + 1.0f;
        mos_lanes limit = zero + INFINITY;  /* each lane's k-th smallest distance (all kept when k = cells) */
        if (k < cells) {
            for (int32_t t = 0; t < k; ++t) smallest[t] = zero + INFINITY;
            for (int32_t a = 0; a < cells; ++a) {
                mos_lanes x;
                memcpy(&x, dist[a], sizeof x);
                for (int32_t t = 0; t < k; ++t) {
                    const mos_lanes s = smallest[t];
                    const mos_mask s_first = s < x;  /* (s < x ? s : x) and the other one, lane by lane */
                    smallest[t] = SELECT_LANES(s_first, s, x);
                    x = SELECT_LANES(s_first, x, s);
                }
            }
            limit = smallest[k - 1];
        }
        mos_lanes total = zero, count = zero;
        for (int32_t a = 0; a < cells; ++a) {
            mos_lanes d, p;
            memcpy(&d, dist[a], sizeof d);
            memcpy(&p, probs[a], sizeof p);
            const mos_mask keep = (d <= limit) & (d <= cutoff);
            total += SELECT_LANES(keep, p, zero);
            count += SELECT_LANES(keep, one, zero);
        }
        for (int32_t lane = 0; lane < filled; ++lane)
            out[batch[lane]] = (float)((double)total[lane] / (double)count[lane]);
        filled = 0;
    }
}

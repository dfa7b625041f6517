/* CPU Gaussian compositor (forward + hand-written backward) for gsslam.mapping.rasterize_cpu.
 *
 * Built at first use with the system C compiler into a small shared library loaded with ctypes
 * (no Python or torch headers): once with REAL=float and once with REAL=double.
 *
 * Work is organised as exact per-pixel lists: pass 1 counts, per pixel, the (pixel, Gaussian) pairs
 * that pass the rules below; pass 2 fills the lists visiting Gaussians front to back, so each list
 * is already sorted by depth; the forward and backward passes then walk only those pairs.
 *
 * Rules (identical to rasterize_reference.py): pixel centres at integer coordinates; a pair exists
 * when 0.5 d^T conic d <= POWER_CUTOFF and o * exp(-power) >= 1/255; alpha = min(0.99, o exp(-power));
 * compositing stops before the first pair that would bring the transmittance below T_MIN.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#ifndef REAL
#define REAL float
#endif
#define SUFFIX_(name, s) name##_##s
#define SUFFIX(name, s) SUFFIX_(name, s)
#ifndef TAG
#define TAG f32
#endif
#define FN(name) SUFFIX(name, TAG)
#ifndef EXP
#define EXP exp
#endif

#define POWER_CUTOFF 4.5
#define ALPHA_MIN (1.0 / 255.0)
#define ALPHA_MAX 0.99
#define T_MIN 1e-4

typedef REAL real;

/* Integer pixel bounding box of Gaussian g clipped to the image; returns 0 when empty. */
static int bbox(const real *mu, int64_t r, int W, int H, int *x0, int *x1, int *y0, int *y1) {
    if (r <= 0) return 0;
    double mx = mu[0], my = mu[1];
    double a = ceil(mx - (double)r), b = floor(mx + (double)r);
    double c = ceil(my - (double)r), d = floor(my + (double)r);
    if (a < 0) a = 0;
    if (c < 0) c = 0;
    if (b > W - 1) b = W - 1;
    if (d > H - 1) d = H - 1;
    if (a > b || c > d) return 0;
    *x0 = (int)a; *x1 = (int)b; *y0 = (int)c; *y1 = (int)d;
    return 1;
}

static inline real pair_power(const real *mu, const real *con, int x, int y) {
    real dx = (real)x - mu[0], dy = (real)y - mu[1];
    return (real)0.5 * (con[0] * dx * dx + con[2] * dy * dy) + con[1] * dx * dy;
}

/* o * exp(-power) of a pair, or -1 when the pair is outside the ellipse or below ALPHA_MIN. */
static inline real pair_alpha_raw(const real *mu, const real *con, real o, int x, int y) {
    real pw = pair_power(mu, con, x, y);
    if (pw > (real)POWER_CUTOFF) return -1;
    real a = o * (real)EXP(-pw);
    return a < (real)ALPHA_MIN ? -1 : a;
}

/* Pass 1: counts[p] = number of pairs of pixel p. Returns the total. */
int64_t FN(count_pairs)(int64_t N, int W, int H, const real *means2d, const real *conics,
                        const real *opac, const int64_t *radii, int32_t *counts) {
    memset(counts, 0, sizeof(int32_t) * (size_t)W * H);
    int64_t total = 0;
    for (int64_t g = 0; g < N; ++g) {
        int x0, x1, y0, y1;
        if (!bbox(means2d + 2 * g, radii[g], W, H, &x0, &x1, &y0, &y1)) continue;
        const real *mu = means2d + 2 * g, *con = conics + 3 * g;
        real o = opac[g];
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                if (pair_alpha_raw(mu, con, o, x, y) < 0) continue;
                counts[(int64_t)y * W + x] += 1;
                total += 1;
            }
    }
    return total;
}

/* Pass 2: fill the lists (offsets[P + 1] from the counts) visiting Gaussians in depth order. */
void FN(fill_pairs)(int64_t N, int W, int H, const real *means2d, const real *conics, const real *opac,
                    const int64_t *radii, const int64_t *order, const int64_t *offsets, int64_t *cursor,
                    int32_t *pair_gid, real *pair_alpha) {
    int64_t P = (int64_t)W * H;
    memcpy(cursor, offsets, sizeof(int64_t) * (size_t)P);
    for (int64_t k = 0; k < N; ++k) {
        int64_t g = order[k];
        int x0, x1, y0, y1;
        if (!bbox(means2d + 2 * g, radii[g], W, H, &x0, &x1, &y0, &y1)) continue;
        const real *mu = means2d + 2 * g, *con = conics + 3 * g;
        real o = opac[g];
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                real a = pair_alpha_raw(mu, con, o, x, y);
                if (a < 0) continue;
                int64_t slot = cursor[(int64_t)y * W + x]++;
                pair_gid[slot] = (int32_t)g;
                pair_alpha[slot] = a < (real)ALPHA_MAX ? a : (real)ALPHA_MAX;
            }
    }
}

/* Forward: out_feat[P, F] = sum w_i f_i, out_T[P] = final transmittance, n_used[P] pairs composited. */
void FN(composite_forward)(int W, int H, int F, const int64_t *offsets, const int32_t *pair_gid,
                           const real *pair_alpha, const real *feat, real *out_feat, real *out_T,
                           int32_t *n_used) {
    int64_t P = (int64_t)W * H;
    for (int64_t p = 0; p < P; ++p) {
        real T = 1;
        real *acc = out_feat + p * F;
        for (int c = 0; c < F; ++c) acc[c] = 0;
        int64_t k = offsets[p], end = offsets[p + 1];
        for (; k < end; ++k) {
            real a = pair_alpha[k];
            real Tn = T * (1 - a);
            if (Tn < (real)T_MIN) break;
            const real *f = feat + (int64_t)pair_gid[k] * F;
            real w = a * T;
            for (int c = 0; c < F; ++c) acc[c] += w * f[c];
            T = Tn;
        }
        out_T[p] = T;
        n_used[p] = (int32_t)(k - offsets[p]);
    }
}

/* Backward of composite_forward (with out_alpha = 1 - out_T) by reverse compositing, as in 3DGS.
 * Gradients are accumulated (+=) into the zero-initialised g_* arrays. */
void FN(composite_backward)(int W, int H, int F, const int64_t *offsets, const int32_t *pair_gid,
                            const real *pair_alpha, const real *means2d, const real *conics,
                            const real *opac, const real *feat, const real *out_T, const int32_t *n_used,
                            const real *g_feat_out, const real *g_alpha_out, real *g_means2d,
                            real *g_conics, real *g_opac, real *g_feat) {
    real S[64];
    if (F > 64) return;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            int64_t p = (int64_t)y * W + x;
            int n = n_used[p];
            if (n == 0) continue;
            const real *go = g_feat_out + p * F;
            real gA = g_alpha_out[p];
            real T_final = out_T[p];
            real T = T_final;
            for (int c = 0; c < F; ++c) S[c] = 0;
            for (int64_t k = offsets[p] + n - 1; k >= offsets[p]; --k) {
                int64_t g = pair_gid[k];
                real a = pair_alpha[k];
                real one_minus = 1 - a;
                real Ti = T / one_minus;
                const real *f = feat + g * F;
                real *gf = g_feat + g * F;
                real w = a * Ti;
                real dL_da = gA * T_final / one_minus;
                for (int c = 0; c < F; ++c) {
                    gf[c] += w * go[c];
                    dL_da += Ti * go[c] * (f[c] - S[c]);
                    S[c] = a * f[c] + one_minus * S[c];
                }
                T = Ti;
                /* alpha = min(0.99, o G): no gradient through the clamp */
                const real *mu = means2d + 2 * g, *con = conics + 3 * g;
                real dx = (real)x - mu[0], dy = (real)y - mu[1];
                real G = (real)EXP(-pair_power(mu, con, x, y));
                real o = opac[g];
                if (o * G >= (real)ALPHA_MAX) continue;
                g_opac[g] += dL_da * G;
                real dL_dpw = -dL_da * o * G;
                g_means2d[2 * g] += -dL_dpw * (con[0] * dx + con[1] * dy);
                g_means2d[2 * g + 1] += -dL_dpw * (con[2] * dy + con[1] * dx);
                g_conics[3 * g] += dL_dpw * (real)0.5 * dx * dx;
                g_conics[3 * g + 1] += dL_dpw * dx * dy;
                g_conics[3 * g + 2] += dL_dpw * (real)0.5 * dy * dy;
            }
        }
}

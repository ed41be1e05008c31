/*
 * Native per-step loops of the Euler-angle EKF (ekf3.py) and the MEKF (mekf.py): the Python reference (Ekf3._row,
 * Mekf.step) statement by statement in double, equal to rounding (numpy's matrix products go through BLAS). The
 * Python classes pack their state into the buffers below (layouts EKF3_*, MEKF_*), call *_run and unpack it.
 *
 *   ekf3_run(acc, gyro, x_out, state, params, flags): acc, gyro float64 3*N (mg, mdps); x_out 3*N (phi, theta,
 *     psi after each step, rad); state EKF3_STATE (in: start, out: end); params EKF3_NPARAMS; flags bit 0
 *     adaptive, bit 1 exact_propagation.
 *   mekf_run(acc, gyro, q_out, state, istate, params, flags): q_out 4*N (wxyz after each step); istate int64
 *     MEKF_ISTATE; flags bit 0 estimate_bias, bit 1 accelerometer low-pass (acc_tau_s > 0).
 */
#include "../_native_buffers.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF /* keep a*b+c as two roundings, like Python */
#endif

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

/* Python's max(-1.0, min(1.0, v)) (NaN → 1.0, as in Python) */
static double py_clip1(double v)
{
    double m = (v < 1.0) ? v : 1.0;
    return (m > -1.0) ? m : -1.0;
}

/* Python's float ** 2 (CPython calls pow) */
static double sq_pow(double v) { return pow(v, 2.0); }

/* C = A·B (bt 0: B is m×p) or A·Bᵀ (bt 1: B is p×m); A n×m, all row-major, C distinct from A and B */
static void matmul(const double *A, const double *B, double *C, int n, int m, int p, int bt)
{
    int i, j, k;
    for (i = 0; i < n; i++) {
        for (j = 0; j < p; j++) {
            double s = 0.0;
            for (k = 0; k < m; k++) s += A[i * m + k] * (bt ? B[j * m + k] : B[k * p + j]);
            C[i * p + j] = s;
        }
    }
}

static void qmul(const double *a, const double *b, double *out)
{
    double aw = a[0], ax = a[1], ay = a[2], az = a[3];
    double bw = b[0], bx = b[1], by = b[2], bz = b[3];
    out[0] = aw * bw - ax * bx - ay * by - az * bz;
    out[1] = aw * bx + ax * bw + ay * bz - az * by;
    out[2] = aw * by - ax * bz + ay * bw + az * bx;
    out[3] = aw * bz + ax * by - ay * bx + az * bw;
}

/* The quaternion of the rotation vector (rx, ry, rz), rad (first order below 1e-12 rad) */
static void quat_exp(double rx, double ry, double rz, double *d)
{
    double ang = sqrt(rx * rx + ry * ry + rz * rz);
    double s = (ang > 1e-12) ? sin(0.5 * ang) / ang : 0.5;
    d[0] = (ang > 1e-12) ? cos(0.5 * ang) : 1.0;
    d[1] = rx * s;
    d[2] = ry * s;
    d[3] = rz * s;
}

/* q = o / |o| */
static void normalized(const double *o, double *q)
{
    double nn = 1.0 / sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + o[3] * o[3]);
    int i;
    for (i = 0; i < 4; i++) q[i] = o[i] * nn;
}

/* S⁻¹ by the adjugate (_inv3 of mekf.py): column j holds rows j+1 × j+2 of S, over det */
static void inv3(const double *S, double *Si)
{
    double c[9], det;
    int i, j;
    for (j = 0; j < 3; j++) {
        const double *r = S + 3 * ((j + 1) % 3), *s = S + 3 * ((j + 2) % 3);
        c[3 * j] = r[1] * s[2] - r[2] * s[1];
        c[3 * j + 1] = r[2] * s[0] - r[0] * s[2];
        c[3 * j + 2] = r[0] * s[1] - r[1] * s[0];
    }
    det = S[0] * c[0] + S[1] * c[1] + S[2] * c[2];
    for (i = 0; i < 9; i++) Si[i] = c[3 * (i % 3) + i / 3] / det;
}

/* The EKF measurement update with innovation e (3), in place: K = P·Hᵀ·(H·P·Hᵀ + var·I)⁻¹ (numpy's solve gives
 * the same to rounding), dx = K·e, P ← sym((I − K·H)·P·(I − K·H)ᵀ + var·K·Kᵀ) (Joseph form). P nb×nb, H 3×nb,
 * nb ≤ 6. Rows of K from `frozen` on are zeroed: those states are not updated (frozen = nb: none). */
static void ekf_update(double *P, const double *H, double var, int nb, int frozen, const double *e, double *dx)
{
    double PHt[18], S[9], Si[9], K[18], KH[36], IKH[36], T[36], Pn[36], KKt[36];
    int i, j;
    matmul(P, H, PHt, nb, nb, 3, 1);
    matmul(H, PHt, S, 3, nb, 3, 0);
    for (i = 0; i < 9; i += 4) S[i] += var;
    inv3(S, Si);
    matmul(PHt, Si, K, nb, 3, 3, 0);
    for (i = 3 * frozen; i < 3 * nb; i++) K[i] = 0.0;
    for (i = 0; i < nb; i++) dx[i] = K[i * 3] * e[0] + K[i * 3 + 1] * e[1] + K[i * 3 + 2] * e[2];
    matmul(K, H, KH, nb, 3, nb, 0);
    for (i = 0; i < nb * nb; i++) IKH[i] = ((i % (nb + 1) == 0) ? 1.0 : 0.0) - KH[i];
    matmul(IKH, P, T, nb, nb, nb, 0);
    matmul(T, IKH, Pn, nb, nb, nb, 1);
    matmul(K, K, KKt, nb, 3, nb, 1);
    for (i = 0; i < nb * nb; i++) Pn[i] = Pn[i] + var * KKt[i];
    for (i = 0; i < nb; i++)
        for (j = 0; j < nb; j++) P[i * nb + j] = 0.5 * (Pn[i * nb + j] + Pn[j * nb + i]);
}

/* ---- ekf3 ---------------------------------------------------------------------------------------------------- */

#define EKF3_X 0     /* x: phi, theta, psi (3) */
#define EKF3_PM 3    /* P (3×3, row-major) */
#define EKF3_INIT 12 /* 1.0 once initialised */
#define EKF3_STATE 13

enum { /* params */
    EKF3_P_DT, EKF3_P_GYRO_VAR, EKF3_P_PROC_VAR, EKF3_P_ACC_VAR, EKF3_P_NORM_GAIN, EKF3_P_MDPS_TO_RADPS, EKF3_NPARAMS
};

#define EKF3_MIN_COS 1e-3

/* quaternion_from_euler + _propagate_exact of ekf3.py */
static void ekf3_propagate_exact(double *x, double rx, double ry, double rz)
{
    double hx = 0.5 * x[0], hy = 0.5 * x[1], hz = 0.5 * x[2];
    double cx = cos(hx), sx = sin(hx), cy = cos(hy), sy = sin(hy), cz = cos(hz), sz = sin(hz);
    double q[4] = {cz * cy * cx + sz * sy * sx, cz * cy * sx - sz * sy * cx, cz * sy * cx + sz * cy * sx,
                   sz * cy * cx - cz * sy * sx};
    double d[4], o[4];
    quat_exp(rx, ry, rz, d);
    qmul(q, d, o);
    const double w = o[0], x_ = o[1], y = o[2], z = o[3];
    x[0] = atan2(2 * (w * x_ + y * z), w * w - x_ * x_ - y * y + z * z);
    x[1] = asin(py_clip1(2 * (w * y - x_ * z)));
    x[2] = atan2(2 * (x_ * y + w * z), w * w + x_ * x_ - y * y - z * z);
}

static void ekf3_predict(double *x, double *P, const double *prm, int exact, double p, double q, double r)
{
    const double dt = prm[EKF3_P_DT];
    double phi = x[0], th = x[1];
    double sp = sin(phi), cp = cos(phi), ct = cos(th), st, tt, a, c, gq, pq;
    double Q[9], FP[9];
    int i;
    if (fabs(ct) < EKF3_MIN_COS) ct = copysign(EKF3_MIN_COS, ct);
    st = sin(th);
    tt = st / ct;
    a = sp * q + cp * r;
    c = cp * q - sp * r;
    const double F[9] = {1.0 + dt * tt * c, dt * a / (ct * ct), 0.0, /* row 0 */
                         -dt * a, 1.0, 0.0,                         /* row 1 */
                         dt * c / ct, dt * a * st / (ct * ct), 1.0};
    const double W[9] = {1.0, sp * tt, cp * tt, 0.0, cp, -sp, 0.0, sp / ct, cp / ct};
    matmul(W, W, Q, 3, 3, 3, 1);
    matmul(F, P, FP, 3, 3, 3, 0);
    matmul(FP, F, P, 3, 3, 3, 1);
    if (exact) {
        ekf3_propagate_exact(x, p * dt, q * dt, r * dt);
    } else {
        x[0] = remainder(x[0] + dt * (p + tt * a), 2 * M_PI);
        x[1] += dt * c;
        x[2] = remainder(x[2] + dt * (a / ct), 2 * M_PI);
    }
    gq = dt * dt * prm[EKF3_P_GYRO_VAR];
    pq = dt * prm[EKF3_P_PROC_VAR];
    for (i = 0; i < 9; i++) {
        Q[i] = gq * Q[i];
        if (i % 4 == 0) Q[i] += pq; /* + dt·σ_p²·I */
        P[i] = P[i] + Q[i];
    }
}

static void ekf3_update(double *x, double *P, const double *prm, int adaptive, double ux, double uy, double uz,
                        double an)
{
    double phi = x[0], th = x[1];
    double sp = sin(phi), cp = cos(phi), st = sin(th), ct = cos(th);
    const double e[3] = {ux - (-st), uy - sp * ct, uz - cp * ct}; /* y − h(x) */
    const double H[9] = {0.0, -ct, 0.0, cp * ct, -sp * st, 0.0, -sp * ct, -cp * st, 0.0};
    double var = prm[EKF3_P_ACC_VAR], d[3];
    int i;
    if (adaptive) var += sq_pow(prm[EKF3_P_NORM_GAIN] * (an - 1.0));
    ekf_update(P, H, var, 3, 3, e, d);
    for (i = 0; i < 3; i++) x[i] += d[i];
}

static PyObject *native_ekf3_run(PyObject *Py_UNUSED(self), PyObject *args)
{
    PyObject *o[5]; /* acc, gyro, x_out, state, params */
    long long flags;
    Py_buffer b[5] = {{0}};
    Py_ssize_t n, k;

    if (!PyArg_ParseTuple(args, "OOOOOL", &o[0], &o[1], &o[2], &o[3], &o[4], &flags)) return NULL;
    if ((n = get_buffer(o[0], &b[0], 0, ROWS_OF(24), "acc")) < 0) return NULL;
    if (get_buffer(o[1], &b[1], 0, 3 * n * 8, "gyro") < 0 || get_buffer(o[2], &b[2], 1, 3 * n * 8, "x_out") < 0 ||
        get_buffer(o[3], &b[3], 1, EKF3_STATE * 8, "state") < 0 ||
        get_buffer(o[4], &b[4], 0, EKF3_NPARAMS * 8, "params") < 0)
        return release(b, 5);
    const double *acc = (const double *)b[0].buf, *gyro = (const double *)b[1].buf;
    double *xo = (double *)b[2].buf, *st = (double *)b[3].buf;
    double *x = st + EKF3_X, *P = st + EKF3_PM; /* the state, updated in place */
    const double *prm = (const double *)b[4].buf, k_rad = prm[EKF3_P_MDPS_TO_RADPS];
    const int adaptive = (int)(flags & 1), exact = (int)((flags >> 1) & 1);
    int init = st[EKF3_INIT] != 0.0;

    Py_BEGIN_ALLOW_THREADS
    for (k = 0; k < n; k++) {
        double ax = acc[3 * k] * 1e-3, ay = acc[3 * k + 1] * 1e-3, az = acc[3 * k + 2] * 1e-3;
        double p = gyro[3 * k] * k_rad, q = gyro[3 * k + 1] * k_rad, r = gyro[3 * k + 2] * k_rad;
        double an = sqrt(ax * ax + ay * ay + az * az);
        int acc_ok = isfinite(an) && an > 1e-6;
        if (!init) {
            if (acc_ok) {
                x[0] = atan2(ay, az);
                x[1] = asin(py_clip1(-ax / an));
                x[2] = 0.0;
                init = 1;
            }
        } else {
            if (isfinite(p) && isfinite(q) && isfinite(r)) ekf3_predict(x, P, prm, exact, p, q, r);
            if (acc_ok) ekf3_update(x, P, prm, adaptive, ax / an, ay / an, az / an, an);
        }
        memcpy(xo + 3 * k, x, 3 * sizeof(double));
    }
    Py_END_ALLOW_THREADS
    st[EKF3_INIT] = init ? 1.0 : 0.0;
    release(b, 5);
    Py_RETURN_NONE;
}

/* ---- mekf ---------------------------------------------------------------------------------------------------- */

#define MEKF_QS 0    /* strapdown quaternion q_s (4) */
#define MEKF_QC 4    /* correction quaternion q_c (4) */
#define MEKF_B 8     /* gyro bias, rad/s (3) */
#define MEKF_W 11    /* last bias-corrected rate, rad/s (3) */
#define MEKF_PM 14   /* P: nb×nb row-major with nb = 6 or 3 (36 slots) */
#define MEKF_CUM 50  /* C = Σ dt·R(q_s) (9) */
#define MEKF_ALP 59  /* accelerometer low-pass: x1, x2, y1, y2, running sum (5×3) */
#define MEKF_NLP 74  /* |a| deviation low-pass: x1, x2, y1, y2 (4×1) */
#define MEKF_CLP 78  /* low-pass of C: x1, x2, y1, y2 (4×9) */
#define MEKF_STATE 114

enum { /* istate */
    MEKF_I_INIT, MEKF_I_ALP_READY, MEKF_I_ALP_N, MEKF_I_ALP_WARMUP, MEKF_I_NLP_READY, MEKF_I_CLP_READY, MEKF_ISTATE
};
enum { /* params (MEKF_P_LP: the low-pass' b0, b1, b2, a1, a2) */
    MEKF_P_DT, MEKF_P_MDPS_TO_RADPS, MEKF_P_REJECT, MEKF_P_Q_ATT, MEKF_P_Q_BIAS, MEKF_P_ACC_NOISE, MEKF_P_NORM_GAIN,
    MEKF_P_INIT_BIAS, MEKF_P_LATENCY, MEKF_P_LP, MEKF_NPARAMS = MEKF_P_LP + 5
};

typedef struct {
    double *st;        /* MEKF_STATE doubles */
    int64_t *ist;      /* MEKF_ISTATE ints */
    const double *prm; /* MEKF_NPARAMS doubles */
    int nb;            /* 6 with bias states, 3 without */
    int estimate_bias, have_lp;
} mekf_t;

static void rotmat(const double *q, double *R)
{
    double w = q[0], x = q[1], y = q[2], z = q[3];
    const double M[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),  /* row 0 */
                         2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),  /* row 1 */
                         2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}; /* row 2 */
    memcpy(R, M, sizeof M);
}

/* _LowPass.__call__ for an m-vector; s = x1, x2, y1, y2 (m each), sum (m, only with a warm-up: n counts its
 * samples, NULL for none); out (m) */
static void lowpass(const double *c, double *s, int m, int64_t *ready, int64_t *n, int64_t warmup, const double *x,
                    double *out)
{
    double *x1 = s, *x2 = s + m, *y1 = s + 2 * m, *y2 = s + 3 * m, *sum = s + 4 * m;
    int i;
    if ((n != NULL && *n < warmup) || !*ready) { /* warming up (the running mean), or the first sample */
        if (n != NULL && *n < warmup) {
            for (i = 0; i < m; i++) sum[i] = (*n == 0) ? x[i] : sum[i] + x[i];
            *n += 1;
        }
        for (i = 0; i < m; i++) {
            const double start = (n != NULL && *n > 0) ? sum[i] / (double)*n : x[i];
            out[i] = x1[i] = x2[i] = y1[i] = y2[i] = start;
        }
        *ready = 1;
        return;
    }
    for (i = 0; i < m; i++) {
        double y = c[0] * x[i] + c[1] * x1[i] + c[2] * x2[i] - c[3] * y1[i] - c[4] * y2[i];
        x2[i] = x1[i];
        x1[i] = x[i];
        y2[i] = y1[i];
        y1[i] = out[i] = y;
    }
}

static void tilt_quat(double ax, double ay, double az, double *q)
{
    const double n = sqrt(ax * ax + ay * ay + az * az);
    const double w = 1.0 + az / n, x = ay / n, y = -(ax / n), s = sqrt(w * w + x * x + y * y);
    q[0] = (w < 1e-9) ? 0.0 : w / s; /* upside down: (0, 1, 0, 0) */
    q[1] = (w < 1e-9) ? 1.0 : x / s;
    q[2] = (w < 1e-9) ? 0.0 : y / s;
    q[3] = 0.0;
}

static void mekf_predict(mekf_t *f, double wx, double wy, double wz)
{
    const double dt = f->prm[MEKF_P_DT];
    double *st = f->st, *P = st + MEKF_PM, *qs = st + MEKF_QS;
    const int nb = f->nb;
    double d[4], o[4];
    int i, j;
    quat_exp(wx * dt, wy * dt, wz * dt, d);
    qmul(qs, d, o);
    normalized(o, qs);
    if (f->estimate_bias) {
        double rs[9], G[9], Pab[9], Pbb[9], GPbb[9], T1[9], T2[9], T3[9];
        double *cum = st + MEKF_CUM;
        const double qb = f->prm[MEKF_P_Q_BIAS];
        rotmat(qs, rs);
        for (i = 0; i < 9; i++) {
            cum[i] += dt * rs[i];
            G[i] = -dt * rs[i];
            Pab[i] = P[(i / 3) * nb + 3 + i % 3];
            Pbb[i] = P[(3 + i / 3) * nb + 3 + i % 3];
        }
        matmul(G, Pbb, GPbb, 3, 3, 3, 0);
        matmul(G, Pab, T1, 3, 3, 3, 1);    /* G·Pabᵀ */
        matmul(Pab, G, T2, 3, 3, 3, 1);    /* Pab·Gᵀ */
        matmul(GPbb, G, T3, 3, 3, 3, 1);   /* GPbb·Gᵀ */
        for (i = 0; i < 3; i++) {
            for (j = 0; j < 3; j++) {
                double v = Pab[i * 3 + j] + GPbb[i * 3 + j];
                P[i * nb + j] += T1[i * 3 + j] + T2[i * 3 + j] + T3[i * 3 + j];
                P[i * nb + 3 + j] = v;
                P[(3 + j) * nb + i] = v;
            }
        }
        for (i = 3; i < 6; i++) P[i * nb + i] += qb;
    }
    for (i = 0; i < 3; i++) P[i * nb + i] += f->prm[MEKF_P_Q_ATT];
}

static void mekf_correct(mekf_t *f, double ax, double ay, double az, double an)
{
    const double *prm = f->prm;
    double *st = f->st, *P = st + MEKF_PM, *qc = st + MEKF_QC;
    int64_t *ist = f->ist;
    const int nb = f->nb;
    const double ng = prm[MEKF_P_NORM_GAIN];
    const double w = qc[0], x = qc[1], y = qc[2], z = qc[3];
    const double hx = 2.0 * (x * z - w * y), hy = 2.0 * (w * x + y * z), hz = w * w - x * x - y * y + z * z;
    const double Hh[9] = {0.0, -hz, hy, hz, 0.0, -hx, -hy, hx, 0.0}; /* [h]× */
    double dev = fabs(an - 1.0), u[3], d, var; /* u: the measured gravity direction */
    double H[18], dxs[6];
    int i;
    int warming = 0;
    if (f->have_lp) {
        double R[9], a_i[3], m[3], mn;
        int64_t *ready = ist + MEKF_I_ALP_READY, *n = ist + MEKF_I_ALP_N;
        rotmat(st + MEKF_QS, R);
        for (i = 0; i < 3; i++) a_i[i] = R[i * 3] * ax + R[i * 3 + 1] * ay + R[i * 3 + 2] * az;
        lowpass(prm + MEKF_P_LP, st + MEKF_ALP, 3, ready, n, ist[MEKF_I_ALP_WARMUP], a_i, m);
        d = 0.0;
        if (ng > 0.0) lowpass(prm + MEKF_P_LP, st + MEKF_NLP, 1, ist + MEKF_I_NLP_READY, NULL, 0, &dev, &d);
        mn = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
        if (mn < 1e-6) return;
        for (i = 0; i < 3; i++) u[i] = m[i] / mn;
        warming = ist[MEKF_I_ALP_N] < ist[MEKF_I_ALP_WARMUP];
    } else {
        u[0] = ax / an;
        u[1] = ay / an;
        u[2] = az / an;
        d = dev;
    }
    var = sq_pow(prm[MEKF_P_ACC_NOISE]) + sq_pow(ng * d);
    for (i = 0; i < 9; i++) H[(i / 3) * nb + i % 3] = Hh[i];
    if (f->estimate_bias) { /* [h]×·D, D = C − LP(C); zero for the direct MEKF and while the low-pass warms up */
        double lpc[9], D[9] = {0.0}, HD[9];
        if (f->have_lp && !warming) {
            lowpass(prm + MEKF_P_LP, st + MEKF_CLP, 9, ist + MEKF_I_CLP_READY, NULL, 0, st + MEKF_CUM, lpc);
            for (i = 0; i < 9; i++) D[i] = st[MEKF_CUM + i] - lpc[i];
        }
        matmul(Hh, D, HD, 3, 3, 3, 0);
        for (i = 0; i < 9; i++) H[(i / 3) * 6 + 3 + i % 3] = HD[i];
    }
    const double e[3] = {u[0] - hx, u[1] - hy, u[2] - hz};
    /* while the low-pass warms up its mean says nothing about the bias: attitude-only update */
    ekf_update(P, H, var, nb, (f->estimate_bias && f->have_lp && warming) ? 3 : nb, e, dxs);
    double dq[4] = {1.0, 0.5 * dxs[0], 0.5 * dxs[1], 0.5 * dxs[2]}, o[4];
    qmul(qc, dq, o);
    normalized(o, qc);
    if (f->estimate_bias) {
        double tr, cap;
        for (i = 0; i < 3; i++) st[MEKF_B + i] += dxs[3 + i];
        tr = P[3 * 6 + 3] + P[4 * 6 + 4] + P[5 * 6 + 5];
        cap = 3 * sq_pow(prm[MEKF_P_INIT_BIAS]);
        if (tr > cap) {
            double sc = cap / tr;
            for (i = 0; i < 9; i++) P[(3 + i / 3) * 6 + 3 + i % 3] *= sc;
        }
    }
}

static void mekf_output(const mekf_t *f, double *out)
{
    const double *st = f->st;
    const double lat = f->prm[MEKF_P_LATENCY];
    qmul(st + MEKF_QC, st + MEKF_QS, out);
    if (lat > 0.0 && (int)f->ist[MEKF_I_INIT]) {
        const double *w = st + MEKF_W;
        double rx = w[0] * lat, ry = w[1] * lat, rz = w[2] * lat, d[4], q[4];
        if (!(sqrt(rx * rx + ry * ry + rz * rz) < 1e-12)) {
            quat_exp(rx, ry, rz, d);
            memcpy(q, out, sizeof q);
            qmul(q, d, out);
        }
    }
}

static PyObject *native_mekf_run(PyObject *Py_UNUSED(self), PyObject *args)
{
    PyObject *o[6]; /* acc, gyro, q_out, state, istate, params */
    long long flags;
    Py_buffer b[6] = {{0}};
    Py_ssize_t n, k;

    if (!PyArg_ParseTuple(args, "OOOOOOL", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &flags)) return NULL;
    if ((n = get_buffer(o[0], &b[0], 0, ROWS_OF(24), "acc")) < 0) return NULL;
    if (get_buffer(o[1], &b[1], 0, 3 * n * 8, "gyro") < 0 || get_buffer(o[2], &b[2], 1, 4 * n * 8, "q_out") < 0 ||
        get_buffer(o[3], &b[3], 1, MEKF_STATE * 8, "state") < 0 ||
        get_buffer(o[4], &b[4], 1, MEKF_ISTATE * 8, "istate") < 0 ||
        get_buffer(o[5], &b[5], 0, MEKF_NPARAMS * 8, "params") < 0)
        return release(b, 6);
    const double *acc = (const double *)b[0].buf, *gyro = (const double *)b[1].buf;
    double *qo = (double *)b[2].buf;
    const double *prm = (const double *)b[5].buf;
    const double k_rad = prm[MEKF_P_MDPS_TO_RADPS], reject = prm[MEKF_P_REJECT];
    mekf_t f = {.st = (double *)b[3].buf, .ist = (int64_t *)b[4].buf, .prm = prm, .nb = (flags & 1) ? 6 : 3,
                .estimate_bias = (int)(flags & 1), .have_lp = (int)((flags >> 1) & 1)};

    Py_BEGIN_ALLOW_THREADS
    for (k = 0; k < n; k++) {
        double ax = acc[3 * k] * 1e-3, ay = acc[3 * k + 1] * 1e-3, az = acc[3 * k + 2] * 1e-3;
        double gx = gyro[3 * k] * k_rad, gy = gyro[3 * k + 1] * k_rad, gz = gyro[3 * k + 2] * k_rad;
        double an = sqrt(ax * ax + ay * ay + az * az);
        int acc_ok = isfinite(an) && an > 1e-6 && fabs(an - 1.0) <= reject;
        if (!f.ist[MEKF_I_INIT]) {
            if (acc_ok) {
                tilt_quat(ax, ay, az, f.st + MEKF_QC);
                f.ist[MEKF_I_INIT] = 1;
            }
            qmul(f.st + MEKF_QC, f.st + MEKF_QS, qo + 4 * k); /* no extrapolation on this step */
            continue;
        }
        if (isfinite(gx) && isfinite(gy) && isfinite(gz)) {
            double *w = f.st + MEKF_W, *bias = f.st + MEKF_B;
            w[0] = gx - bias[0];
            w[1] = gy - bias[1];
            w[2] = gz - bias[2];
            mekf_predict(&f, w[0], w[1], w[2]);
        }
        if (acc_ok) mekf_correct(&f, ax, ay, az, an);
        mekf_output(&f, qo + 4 * k);
    }
    Py_END_ALLOW_THREADS
    release(b, 6);
    Py_RETURN_NONE;
}

static PyMethodDef native_methods[] = {
    {"ekf3_run", native_ekf3_run, METH_VARARGS, "Ekf3's per-step loop over N steps, in place (see _ekf_native.c)."},
    {"mekf_run", native_mekf_run, METH_VARARGS, "Mekf's per-step loop over N steps, in place (see _ekf_native.c)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef native_module = {
    PyModuleDef_HEAD_INIT, "_ekf_native",
    "Native per-step loops of the ekf3 and mekf estimators (see ekf3.py, mekf.py).", -1, native_methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__ekf_native(void)
{
    PyObject *m = PyModule_Create(&native_module);
    if (m == NULL) return NULL;
    if (PyModule_AddIntConstant(m, "EKF3_STATE", EKF3_STATE) < 0 ||
        PyModule_AddIntConstant(m, "MEKF_STATE", MEKF_STATE) < 0 ||
        PyModule_AddIntConstant(m, "MEKF_ISTATE", MEKF_ISTATE) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}

/*
 * Native per-step loops of steval-link's two Kalman filters: the 3-state Euler-angle EKF (ekf3.py) and the
 * multiplicative EKF with inertial-frame accelerometer averaging (mekf.py).
 *
 * Written for steval-link. Each loop follows the Python reference (Ekf3._advance, Mekf.step) statement by
 * statement in double precision and in the same evaluation order, so the two agree to rounding (numpy's 3×3 /
 * 6×6 products go through BLAS, whose summation order and FMA use differ: the results agree to ~1e-15, not bit
 * for bit). Build flags: -O2 -ffp-contract=off -fno-fast-math -std=c99 (setup.py). The Python classes pack their
 * state into the buffers below, call run_*, and unpack the final state, so step() continues where run() ended.
 *
 * Python signatures (called by ekf3.py / mekf.py, which validate shapes and dtypes):
 *
 *   ekf3_run(acc, gyro, x_out, state, params, flags) -> None
 *     acc, gyro : float64 buffers of 3*N values (mg, mdps), C order
 *     x_out     : writable float64 buffer of 3*N values: (phi, theta, psi) after each step, rad
 *     state     : writable float64 buffer of EKF3_STATE values (layout EKF3_*; in: start, out: end)
 *     params    : float64 buffer of EKF3_NPARAMS values (EKF3_P_*)
 *     flags     : int: bit 0 adaptive, bit 1 exact_propagation
 *
 *   mekf_run(acc, gyro, q_out, state, istate, params, flags) -> None
 *     acc, gyro : float64 buffers of 3*N values (mg, mdps), C order
 *     q_out     : writable float64 buffer of 4*N values: the returned attitude (wxyz) after each step
 *     state     : writable float64 buffer of MEKF_STATE values (layout MEKF_*; in: start, out: end)
 *     istate    : writable int64 buffer of MEKF_ISTATE values (MEKF_I_*; in: start, out: end)
 *     params    : float64 buffer of MEKF_NPARAMS values (MEKF_P_*)
 *     flags     : int: bit 0 estimate_bias, bit 1 accelerometer low-pass (acc_tau_s > 0)
 *
 * The layouts are mirrored by the _pack/_unpack helpers in ekf3.py and mekf.py (the constants are exported as
 * module attributes and checked there).
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

/* ------------------------------------------------------------------------------------------------------------
 * Helpers shared by both filters
 * ------------------------------------------------------------------------------------------------------------ */

/* Python's max(-1.0, min(1.0, v)) (NaN → 1.0, as in Python) */
static double py_clip1(double v)
{
    double m = (v < 1.0) ? v : 1.0;
    return (m > -1.0) ? m : -1.0;
}

/* Python's float ** 2 (CPython calls pow) */
static double sq_pow(double v) { return pow(v, 2.0); }

/* C = A·B, A (n×m), B (m×p), all row-major, C distinct from A and B */
static void matmul(const double *A, const double *B, double *C, int n, int m, int p)
{
    int i, j, k;
    for (i = 0; i < n; i++) {
        for (j = 0; j < p; j++) {
            double s = 0.0;
            for (k = 0; k < m; k++) s += A[i * m + k] * B[k * p + j];
            C[i * p + j] = s;
        }
    }
}

/* C = A·Bᵀ, A (n×m), B (p×m) */
static void matmul_bt(const double *A, const double *B, double *C, int n, int m, int p)
{
    int i, j, k;
    for (i = 0; i < n; i++) {
        for (j = 0; j < p; j++) {
            double s = 0.0;
            for (k = 0; k < m; k++) s += A[i * m + k] * B[j * m + k];
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

/* ------------------------------------------------------------------------------------------------------------
 * ekf3
 * ------------------------------------------------------------------------------------------------------------ */

#define EKF3_X 0     /* x: phi, theta, psi (3) */
#define EKF3_PM 3    /* P (3×3, row-major) */
#define EKF3_INIT 12 /* 1.0 once initialised */
#define EKF3_STATE 13

#define EKF3_P_DT 0
#define EKF3_P_GYRO_VAR 1
#define EKF3_P_PROC_VAR 2
#define EKF3_P_ACC_VAR 3
#define EKF3_P_NORM_GAIN 4
#define EKF3_P_MDPS_TO_RADPS 5
#define EKF3_NPARAMS 6

#define EKF3_MIN_COS 1e-3

/* quaternion_from_euler + _propagate_exact of ekf3.py */
static void ekf3_propagate_exact(double *x, double rx, double ry, double rz)
{
    double hx = 0.5 * x[0], hy = 0.5 * x[1], hz = 0.5 * x[2];
    double cx = cos(hx), sx = sin(hx), cy = cos(hy), sy = sin(hy), cz = cos(hz), sz = sin(hz);
    double qw = cz * cy * cx + sz * sy * sx;
    double qx = cz * cy * sx - sz * sy * cx;
    double qy = cz * sy * cx + sz * cy * sx;
    double qz = sz * cy * cx - cz * sy * sx;
    double ang = sqrt(rx * rx + ry * ry + rz * rz);
    double dw, dx, dy, dz, w, x_, y, z;
    if (ang > 1e-12) {
        double sn = sin(0.5 * ang) / ang;
        dw = cos(0.5 * ang);
        dx = rx * sn;
        dy = ry * sn;
        dz = rz * sn;
    } else {
        dw = 1.0;
        dx = 0.5 * rx;
        dy = 0.5 * ry;
        dz = 0.5 * rz;
    }
    w = qw * dw - qx * dx - qy * dy - qz * dz;
    x_ = qw * dx + qx * dw + qy * dz - qz * dy;
    y = qw * dy - qx * dz + qy * dw + qz * dx;
    z = qw * dz + qx * dy - qy * dx + qz * dw;
    x[0] = atan2(2 * (w * x_ + y * z), w * w - x_ * x_ - y * y + z * z);
    x[1] = asin(py_clip1(2 * (w * y - x_ * z)));
    x[2] = atan2(2 * (x_ * y + w * z), w * w + x_ * x_ - y * y - z * z);
}

static void ekf3_predict(double *x, double *P, const double *prm, int exact, double p, double q, double r)
{
    const double dt = prm[EKF3_P_DT];
    double phi = x[0], th = x[1];
    double sp = sin(phi), cp = cos(phi), ct = cos(th), st, tt, a, c, f0, f1, f2, gq, pq;
    double F[9], W[9], Q[9], FP[9];
    if (fabs(ct) < EKF3_MIN_COS) ct = copysign(EKF3_MIN_COS, ct);
    st = sin(th);
    tt = st / ct;
    a = sp * q + cp * r;
    c = cp * q - sp * r;
    f0 = p + tt * a;
    f1 = c;
    f2 = a / ct;
    F[0] = 1.0 + dt * tt * c;
    F[1] = dt * a / (ct * ct);
    F[2] = 0.0;
    F[3] = -dt * a;
    F[4] = 1.0;
    F[5] = 0.0;
    F[6] = dt * c / ct;
    F[7] = dt * a * st / (ct * ct);
    F[8] = 1.0;
    W[0] = 1.0;
    W[1] = sp * tt;
    W[2] = cp * tt;
    W[3] = 0.0;
    W[4] = cp;
    W[5] = -sp;
    W[6] = 0.0;
    W[7] = sp / ct;
    W[8] = cp / ct;
    if (exact) {
        ekf3_propagate_exact(x, p * dt, q * dt, r * dt);
    } else {
        x[0] = remainder(x[0] + dt * f0, 2 * M_PI);
        x[1] += dt * f1;
        x[2] = remainder(x[2] + dt * f2, 2 * M_PI);
    }
    matmul_bt(W, W, Q, 3, 3, 3);
    gq = dt * dt * prm[EKF3_P_GYRO_VAR];
    {
        int i;
        for (i = 0; i < 9; i++) Q[i] = gq * Q[i];
    }
    pq = dt * prm[EKF3_P_PROC_VAR];
    Q[0] += pq;
    Q[4] += pq;
    Q[8] += pq;
    matmul(F, P, FP, 3, 3, 3);
    matmul_bt(FP, F, P, 3, 3, 3);
    {
        int i;
        for (i = 0; i < 9; i++) P[i] = P[i] + Q[i];
    }
}

/* X = S⁻¹·B for a 3×3 S and 3 right-hand sides (B 3×3), Gaussian elimination with partial pivoting */
static void solve3(const double *S_in, const double *B_in, double *X)
{
    double S[9], B[9];
    int i, j, k;
    memcpy(S, S_in, sizeof S);
    memcpy(B, B_in, sizeof B);
    for (k = 0; k < 3; k++) {
        int piv = k;
        double best = fabs(S[k * 3 + k]);
        for (i = k + 1; i < 3; i++) {
            if (fabs(S[i * 3 + k]) > best) {
                best = fabs(S[i * 3 + k]);
                piv = i;
            }
        }
        if (piv != k) {
            for (j = 0; j < 3; j++) {
                double t = S[k * 3 + j];
                S[k * 3 + j] = S[piv * 3 + j];
                S[piv * 3 + j] = t;
                t = B[k * 3 + j];
                B[k * 3 + j] = B[piv * 3 + j];
                B[piv * 3 + j] = t;
            }
        }
        for (i = k + 1; i < 3; i++) {
            double l = S[i * 3 + k] / S[k * 3 + k];
            for (j = k; j < 3; j++) S[i * 3 + j] -= l * S[k * 3 + j];
            for (j = 0; j < 3; j++) B[i * 3 + j] -= l * B[k * 3 + j];
        }
    }
    for (k = 2; k >= 0; k--) {
        for (j = 0; j < 3; j++) {
            double s = B[k * 3 + j];
            for (i = k + 1; i < 3; i++) s -= S[k * 3 + i] * X[i * 3 + j];
            X[k * 3 + j] = s / S[k * 3 + k];
        }
    }
}

static void ekf3_update(double *x, double *P, const double *prm, int adaptive, double ux, double uy, double uz,
                        double an)
{
    double phi = x[0], th = x[1];
    double sp = sin(phi), cp = cos(phi), st = sin(th), ct = cos(th);
    double h0 = -st, h1 = sp * ct, h2 = cp * ct, e0, e1, e2;
    double H[9], PHt[9], S[9], PHtT[9], X[9], K[9], KH[9], IKH[9], T[9], Pn[9], KKt[9];
    double var = prm[EKF3_P_ACC_VAR];
    int i, j;
    H[0] = 0.0;
    H[1] = -ct;
    H[2] = 0.0;
    H[3] = cp * ct;
    H[4] = -sp * st;
    H[5] = 0.0;
    H[6] = -sp * ct;
    H[7] = -cp * st;
    H[8] = 0.0;
    if (adaptive) var += sq_pow(prm[EKF3_P_NORM_GAIN] * (an - 1.0));
    matmul_bt(P, H, PHt, 3, 3, 3);
    matmul(H, PHt, S, 3, 3, 3);
    S[0] += var;
    S[4] += var;
    S[8] += var;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) PHtT[i * 3 + j] = PHt[j * 3 + i];
    solve3(S, PHtT, X); /* K = solve(S, PHtᵀ)ᵀ */
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) K[i * 3 + j] = X[j * 3 + i];
    e0 = ux - h0;
    e1 = uy - h1;
    e2 = uz - h2;
    {
        double d0 = K[0] * e0 + K[1] * e1 + K[2] * e2;
        double d1 = K[3] * e0 + K[4] * e1 + K[5] * e2;
        double d2 = K[6] * e0 + K[7] * e1 + K[8] * e2;
        x[0] += d0;
        x[1] += d1;
        x[2] += d2;
    }
    matmul(K, H, KH, 3, 3, 3);
    for (i = 0; i < 9; i++) IKH[i] = ((i % 4 == 0) ? 1.0 : 0.0) - KH[i];
    matmul(IKH, P, T, 3, 3, 3);
    matmul_bt(T, IKH, Pn, 3, 3, 3);
    matmul_bt(K, K, KKt, 3, 3, 3);
    for (i = 0; i < 9; i++) Pn[i] = Pn[i] + var * KKt[i];
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) P[i * 3 + j] = 0.5 * (Pn[i * 3 + j] + Pn[j * 3 + i]);
}

static PyObject *native_ekf3_run(PyObject *self, PyObject *args)
{
    PyObject *o_acc, *o_gyro, *o_x, *o_state, *o_params;
    long long flags;
    Py_buffer b_acc = {0}, b_gyro = {0}, b_x = {0}, b_state = {0}, b_params = {0};
    Py_ssize_t n, k;
    int ok = 0;

    (void)self;
    if (!PyArg_ParseTuple(args, "OOOOOL", &o_acc, &o_gyro, &o_x, &o_state, &o_params, &flags)) return NULL;
    if ((n = get_rows(o_acc, &b_acc, 3 * sizeof(double), "acc")) < 0) return NULL;
    if (get_buffer(o_gyro, &b_gyro, 0, 3 * n * 8, "gyro") < 0 || get_buffer(o_x, &b_x, 1, 3 * n * 8, "x_out") < 0 ||
        get_buffer(o_state, &b_state, 1, EKF3_STATE * 8, "state") < 0 ||
        get_buffer(o_params, &b_params, 0, EKF3_NPARAMS * 8, "params") < 0)
        goto out;
    {
        const double *acc = (const double *)b_acc.buf;
        const double *gyro = (const double *)b_gyro.buf;
        double *xo = (double *)b_x.buf;
        double *st = (double *)b_state.buf;
        double prm[EKF3_NPARAMS];
        const int adaptive = (int)(flags & 1), exact = (int)((flags >> 1) & 1);
        double x[3], P[9];
        int init = st[EKF3_INIT] != 0.0;
        double k_rad;
        memcpy(prm, b_params.buf, sizeof prm);
        k_rad = prm[EKF3_P_MDPS_TO_RADPS];
        memcpy(x, st + EKF3_X, sizeof x);
        memcpy(P, st + EKF3_PM, sizeof P);

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
            xo[3 * k] = x[0];
            xo[3 * k + 1] = x[1];
            xo[3 * k + 2] = x[2];
        }
        Py_END_ALLOW_THREADS

        memcpy(st + EKF3_X, x, sizeof x);
        memcpy(st + EKF3_PM, P, sizeof P);
        st[EKF3_INIT] = init ? 1.0 : 0.0;
    }
    ok = 1;
out:
    PyBuffer_Release(&b_params);
    PyBuffer_Release(&b_state);
    PyBuffer_Release(&b_x);
    PyBuffer_Release(&b_gyro);
    PyBuffer_Release(&b_acc);
    if (!ok) return NULL;
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------------------------------------------------
 * mekf
 * ------------------------------------------------------------------------------------------------------------ */

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

#define MEKF_I_INIT 0
#define MEKF_I_ALP_READY 1
#define MEKF_I_ALP_N 2
#define MEKF_I_ALP_WARMUP 3
#define MEKF_I_NLP_READY 4
#define MEKF_I_CLP_READY 5
#define MEKF_ISTATE 6

#define MEKF_P_DT 0
#define MEKF_P_MDPS_TO_RADPS 1
#define MEKF_P_REJECT 2
#define MEKF_P_Q_ATT 3
#define MEKF_P_Q_BIAS 4
#define MEKF_P_ACC_NOISE 5
#define MEKF_P_NORM_GAIN 6
#define MEKF_P_INIT_BIAS 7
#define MEKF_P_LATENCY 8
#define MEKF_P_LP 9 /* b0, b1, b2, a1, a2 */
#define MEKF_NPARAMS 14

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
    R[0] = 1 - 2 * (y * y + z * z);
    R[1] = 2 * (x * y - w * z);
    R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z);
    R[4] = 1 - 2 * (x * x + z * z);
    R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y);
    R[7] = 2 * (y * z + w * x);
    R[8] = 1 - 2 * (x * x + y * y);
}

/* _LowPass.__call__ for an m-vector; s = x1, x2, y1, y2 (m each), sum (m, only with warmup > 0); out (m) */
static void lowpass(const double *c, double *s, int m, int *ready, int64_t *n, int64_t warmup, const double *x,
                    double *out)
{
    double *x1 = s, *x2 = s + m, *y1 = s + 2 * m, *y2 = s + 3 * m, *sum = s + 4 * m;
    int i;
    if (*n < warmup) {
        for (i = 0; i < m; i++) sum[i] = (*n == 0) ? x[i] : sum[i] + x[i];
        *n += 1;
        for (i = 0; i < m; i++) {
            out[i] = sum[i] / (double)*n;
            x1[i] = x2[i] = y1[i] = y2[i] = out[i];
        }
        *ready = 1;
        return;
    }
    if (!*ready) {
        for (i = 0; i < m; i++) out[i] = x1[i] = x2[i] = y1[i] = y2[i] = x[i];
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
    double n = sqrt(ax * ax + ay * ay + az * az), w, x, y, s;
    ax = ax / n;
    ay = ay / n;
    az = az / n;
    w = 1.0 + az;
    if (w < 1e-9) {
        q[0] = 0.0;
        q[1] = 1.0;
        q[2] = 0.0;
        q[3] = 0.0;
        return;
    }
    x = ay;
    y = -ax;
    s = sqrt(w * w + x * x + y * y);
    q[0] = w / s;
    q[1] = x / s;
    q[2] = y / s;
    q[3] = 0.0;
}

static void mekf_predict(mekf_t *f, double wx, double wy, double wz)
{
    const double dt = f->prm[MEKF_P_DT];
    double *st = f->st, *P = st + MEKF_PM, *qs = st + MEKF_QS;
    const int nb = f->nb;
    double rx = wx * dt, ry = wy * dt, rz = wz * dt;
    double ang = sqrt(rx * rx + ry * ry + rz * rz);
    double d[4], o[4], nn;
    int i, j;
    if (ang > 1e-12) {
        double s = sin(0.5 * ang) / ang;
        d[0] = cos(0.5 * ang);
        d[1] = rx * s;
        d[2] = ry * s;
        d[3] = rz * s;
    } else {
        d[0] = 1.0;
        d[1] = 0.5 * rx;
        d[2] = 0.5 * ry;
        d[3] = 0.5 * rz;
    }
    qmul(qs, d, o);
    nn = 1.0 / sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + o[3] * o[3]);
    for (i = 0; i < 4; i++) qs[i] = o[i] * nn;
    if (f->estimate_bias) {
        double rs[9], G[9], Pab[9], Pbb[9], GPbb[9], T1[9], T2[9], T3[9];
        double *cum = st + MEKF_CUM;
        const double qb = f->prm[MEKF_P_Q_BIAS];
        rotmat(qs, rs);
        for (i = 0; i < 9; i++) {
            cum[i] += dt * rs[i];
            G[i] = -dt * rs[i];
        }
        for (i = 0; i < 3; i++) {
            for (j = 0; j < 3; j++) {
                Pab[i * 3 + j] = P[i * nb + 3 + j];
                Pbb[i * 3 + j] = P[(3 + i) * nb + 3 + j];
            }
        }
        matmul(G, Pbb, GPbb, 3, 3, 3);
        matmul_bt(G, Pab, T1, 3, 3, 3);    /* G·Pabᵀ */
        matmul_bt(Pab, G, T2, 3, 3, 3);    /* Pab·Gᵀ */
        matmul_bt(GPbb, G, T3, 3, 3, 3);   /* GPbb·Gᵀ */
        for (i = 0; i < 3; i++) {
            for (j = 0; j < 3; j++) {
                P[i * nb + j] += T1[i * 3 + j] + T2[i * 3 + j] + T3[i * 3 + j];
            }
        }
        for (i = 0; i < 3; i++) {
            for (j = 0; j < 3; j++) {
                double v = Pab[i * 3 + j] + GPbb[i * 3 + j];
                P[i * nb + 3 + j] = v;
                P[(3 + j) * nb + i] = v;
            }
        }
        P[3 * nb + 3] += qb;
        P[4 * nb + 4] += qb;
        P[5 * nb + 5] += qb;
    }
    {
        const double qa = f->prm[MEKF_P_Q_ATT];
        P[0] += qa;
        P[nb + 1] += qa;
        P[2 * nb + 2] += qa;
    }
}

/* _inv3 of mekf.py: adjugate divided by the determinant */
static void inv3(const double *S, double *Si)
{
    double a = S[0], b = S[1], c = S[2], d = S[3], e = S[4], f = S[5], g = S[6], h = S[7], i = S[8];
    double A = e * i - f * h, B = f * g - d * i, C = d * h - e * g;
    double det = a * A + b * B + c * C;
    Si[0] = A / det;
    Si[1] = (c * h - b * i) / det;
    Si[2] = (b * f - c * e) / det;
    Si[3] = B / det;
    Si[4] = (a * i - c * g) / det;
    Si[5] = (c * d - a * f) / det;
    Si[6] = C / det;
    Si[7] = (b * g - a * h) / det;
    Si[8] = (a * e - b * d) / det;
}

static void mekf_correct(mekf_t *f, double ax, double ay, double az, double an)
{
    const double *prm = f->prm;
    double *st = f->st, *P = st + MEKF_PM, *qc = st + MEKF_QC;
    int64_t *ist = f->ist;
    const int nb = f->nb;
    const double ng = prm[MEKF_P_NORM_GAIN];
    double dev = fabs(an - 1.0), ux, uy, uz, d, var, hx, hy, hz, w, x, y, z, nn;
    double Hh[9], H[18], PHt[18], S[9], Si[9], K[18], dxs[6], KH[36], IKH[36], T[36], Pn[36], KKt[36];
    int i, j, kk;
    int warming = 0;
    if (f->have_lp) {
        double R[9], a_i[3], m[3], mn;
        int ready = (int)ist[MEKF_I_ALP_READY];
        rotmat(st + MEKF_QS, R);
        for (i = 0; i < 3; i++) a_i[i] = R[i * 3] * ax + R[i * 3 + 1] * ay + R[i * 3 + 2] * az;
        lowpass(prm + MEKF_P_LP, st + MEKF_ALP, 3, &ready, &ist[MEKF_I_ALP_N], ist[MEKF_I_ALP_WARMUP], a_i, m);
        ist[MEKF_I_ALP_READY] = ready;
        if (ng > 0.0) {
            int64_t n0 = 0;
            ready = (int)ist[MEKF_I_NLP_READY];
            lowpass(prm + MEKF_P_LP, st + MEKF_NLP, 1, &ready, &n0, 0, &dev, &d);
            ist[MEKF_I_NLP_READY] = ready;
        } else {
            d = 0.0;
        }
        mn = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
        if (mn < 1e-6) return;
        ux = m[0] / mn;
        uy = m[1] / mn;
        uz = m[2] / mn;
        warming = ist[MEKF_I_ALP_N] < ist[MEKF_I_ALP_WARMUP];
    } else {
        ux = ax / an;
        uy = ay / an;
        uz = az / an;
        d = dev;
    }
    var = sq_pow(prm[MEKF_P_ACC_NOISE]) + sq_pow(ng * d);
    w = qc[0];
    x = qc[1];
    y = qc[2];
    z = qc[3];
    hx = 2.0 * (x * z - w * y);
    hy = 2.0 * (w * x + y * z);
    hz = w * w - x * x - y * y + z * z;
    Hh[0] = 0.0;
    Hh[1] = -hz;
    Hh[2] = hy;
    Hh[3] = hz;
    Hh[4] = 0.0;
    Hh[5] = -hx;
    Hh[6] = -hy;
    Hh[7] = hx;
    Hh[8] = 0.0;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) H[i * nb + j] = Hh[i * 3 + j];
    if (f->estimate_bias) {
        if (f->have_lp && !warming) {
            double lpc[9], D[9], HD[9];
            int ready = (int)ist[MEKF_I_CLP_READY];
            const double *cum = st + MEKF_CUM;
            int64_t n0 = 0;
            lowpass(prm + MEKF_P_LP, st + MEKF_CLP, 9, &ready, &n0, 0, cum, lpc);
            ist[MEKF_I_CLP_READY] = ready;
            for (i = 0; i < 9; i++) D[i] = cum[i] - lpc[i];
            matmul(Hh, D, HD, 3, 3, 3);
            for (i = 0; i < 3; i++)
                for (j = 0; j < 3; j++) H[i * 6 + 3 + j] = HD[i * 3 + j];
        } else {
            for (i = 0; i < 3; i++)
                for (j = 0; j < 3; j++) H[i * 6 + 3 + j] = 0.0;
        }
    }
    matmul_bt(P, H, PHt, nb, nb, 3);
    matmul(H, PHt, S, 3, nb, 3);
    S[0] += var;
    S[4] += var;
    S[8] += var;
    inv3(S, Si);
    matmul(PHt, Si, K, nb, 3, 3);
    if (f->estimate_bias && f->have_lp && warming) {
        for (i = 9; i < 18; i++) K[i] = 0.0;
    }
    {
        double e0 = ux - hx, e1 = uy - hy, e2 = uz - hz;
        for (i = 0; i < nb; i++) dxs[i] = K[i * 3] * e0 + K[i * 3 + 1] * e1 + K[i * 3 + 2] * e2;
    }
    matmul(K, H, KH, nb, 3, nb);
    for (i = 0; i < nb; i++)
        for (j = 0; j < nb; j++) IKH[i * nb + j] = ((i == j) ? 1.0 : 0.0) - KH[i * nb + j];
    matmul(IKH, P, T, nb, nb, nb);
    matmul_bt(T, IKH, Pn, nb, nb, nb);
    matmul_bt(K, K, KKt, nb, 3, nb);
    for (kk = 0; kk < nb * nb; kk++) Pn[kk] = Pn[kk] + var * KKt[kk];
    for (i = 0; i < nb; i++)
        for (j = 0; j < nb; j++) P[i * nb + j] = 0.5 * (Pn[i * nb + j] + Pn[j * nb + i]);
    {
        double e[4], o[4];
        e[0] = 1.0;
        e[1] = 0.5 * dxs[0];
        e[2] = 0.5 * dxs[1];
        e[3] = 0.5 * dxs[2];
        qmul(qc, e, o);
        nn = 1.0 / sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + o[3] * o[3]);
        for (i = 0; i < 4; i++) qc[i] = o[i] * nn;
    }
    if (f->estimate_bias) {
        double *b = st + MEKF_B, tr, cap;
        b[0] += dxs[3];
        b[1] += dxs[4];
        b[2] += dxs[5];
        tr = P[3 * 6 + 3] + P[4 * 6 + 4] + P[5 * 6 + 5];
        cap = 3 * sq_pow(prm[MEKF_P_INIT_BIAS]);
        if (tr > cap) {
            double sc = cap / tr;
            for (i = 3; i < 6; i++)
                for (j = 3; j < 6; j++) P[i * 6 + j] *= sc;
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
        double rx = w[0] * lat, ry = w[1] * lat, rz = w[2] * lat;
        double ang = sqrt(rx * rx + ry * ry + rz * rz);
        if (!(ang < 1e-12)) {
            double s = sin(0.5 * ang) / ang, d[4], q[4];
            d[0] = cos(0.5 * ang);
            d[1] = rx * s;
            d[2] = ry * s;
            d[3] = rz * s;
            memcpy(q, out, sizeof q);
            qmul(q, d, out);
        }
    }
}

static PyObject *native_mekf_run(PyObject *self, PyObject *args)
{
    PyObject *o_acc, *o_gyro, *o_q, *o_state, *o_istate, *o_params;
    long long flags;
    Py_buffer b_acc = {0}, b_gyro = {0}, b_q = {0}, b_state = {0}, b_istate = {0}, b_params = {0};
    Py_ssize_t n, k;
    int ok = 0;

    (void)self;
    if (!PyArg_ParseTuple(args, "OOOOOOL", &o_acc, &o_gyro, &o_q, &o_state, &o_istate, &o_params, &flags)) {
        return NULL;
    }
    if ((n = get_rows(o_acc, &b_acc, 3 * sizeof(double), "acc")) < 0) return NULL;
    if (get_buffer(o_gyro, &b_gyro, 0, 3 * n * 8, "gyro") < 0 || get_buffer(o_q, &b_q, 1, 4 * n * 8, "q_out") < 0 ||
        get_buffer(o_state, &b_state, 1, MEKF_STATE * 8, "state") < 0 ||
        get_buffer(o_istate, &b_istate, 1, MEKF_ISTATE * 8, "istate") < 0 ||
        get_buffer(o_params, &b_params, 0, MEKF_NPARAMS * 8, "params") < 0)
        goto out;
    {
        const double *acc = (const double *)b_acc.buf;
        const double *gyro = (const double *)b_gyro.buf;
        double *qo = (double *)b_q.buf;
        double prm[MEKF_NPARAMS];
        mekf_t f;
        double k_rad, reject;
        memcpy(prm, b_params.buf, sizeof prm);
        f.st = (double *)b_state.buf;
        f.ist = (int64_t *)b_istate.buf;
        f.prm = prm;
        f.estimate_bias = (int)(flags & 1);
        f.have_lp = (int)((flags >> 1) & 1);
        f.nb = f.estimate_bias ? 6 : 3;
        k_rad = prm[MEKF_P_MDPS_TO_RADPS];
        reject = prm[MEKF_P_REJECT];

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
                double *w = f.st + MEKF_W, *b = f.st + MEKF_B;
                w[0] = gx - b[0];
                w[1] = gy - b[1];
                w[2] = gz - b[2];
                mekf_predict(&f, w[0], w[1], w[2]);
            }
            if (acc_ok) mekf_correct(&f, ax, ay, az, an);
            mekf_output(&f, qo + 4 * k);
        }
        Py_END_ALLOW_THREADS
    }
    ok = 1;
out:
    PyBuffer_Release(&b_params);
    PyBuffer_Release(&b_istate);
    PyBuffer_Release(&b_state);
    PyBuffer_Release(&b_q);
    PyBuffer_Release(&b_gyro);
    PyBuffer_Release(&b_acc);
    if (!ok) return NULL;
    Py_RETURN_NONE;
}

static PyMethodDef native_methods[] = {
    {"ekf3_run", native_ekf3_run, METH_VARARGS,
     "ekf3_run(acc, gyro, x_out, state, params, flags): Ekf3's per-step loop over N steps, in place."},
    {"mekf_run", native_mekf_run, METH_VARARGS,
     "mekf_run(acc, gyro, q_out, state, istate, params, flags): Mekf's per-step loop over N steps, in place."},
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
        PyModule_AddIntConstant(m, "EKF3_NPARAMS", EKF3_NPARAMS) < 0 ||
        PyModule_AddIntConstant(m, "MEKF_STATE", MEKF_STATE) < 0 ||
        PyModule_AddIntConstant(m, "MEKF_ISTATE", MEKF_ISTATE) < 0 ||
        PyModule_AddIntConstant(m, "MEKF_NPARAMS", MEKF_NPARAMS) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}

/*
 * Native loop of the bit-exact replica of the STEVAL-FCU001V1 Mahony filter (ST releases 170120 and 221117),
 * written for steval-link: ahrs_fusion_ag and QuaternionToEuler in float32, operation by operation in the drone's
 * order (-O0, hard float, no FMA); only atan2/asin run in double. Build: -O2 -ffp-contract=off -fno-fast-math.
 *
 *   run(acc, gyro, thr, q_out, thx_out, thy_out, state, params, flags): acc, gyro float32 3*N (mg, mdps); thr
 *     int64 N; q_out float32 4*N; thx_out, thy_out float32 N (rad) or None; state float32 q0..q3, exInt, eyInt,
 *     ezInt (in: start, out: end); params float64 kp_ground, kp_flight, ki, dt_s; flags: min_thr in bits 0..31,
 *     bit 32 no correction, bit 33 ST 221117's arithmetic.
 *   euler(q, thx_out, thy_out): QuaternionToEuler of 4*N float32 values.
 */
#include "_native_buffers.h"

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF /* clang contracts a*b+c by default on AArch64; GCC uses -ffp-contract=off */
#endif

#if defined(FLT_EVAL_METHOD) && FLT_EVAL_METHOD != 0 && FLT_EVAL_METHOD != -1
#error "float expressions must be evaluated in float (FLT_EVAL_METHOD 0) for bit-exact results"
#endif

/* COE_MDPS_TO_RADPS is the double literal 1.745329252e-5: cast to float where 170120 uses it, double in 221117. */
#define COE_MDPS_TO_RADPS 1.745329252e-5
#define COE_MDPS_TO_RADPS_F ((float)COE_MDPS_TO_RADPS)

static float inv_sqrt(float x)
{
    float halfx = 0.5f * x;
    float y = x;
    int32_t i;
    uint32_t u;
    memcpy(&i, &y, sizeof i);
    /* the firmware's 32-bit `long`: arithmetic shift, then a subtraction that wraps (done unsigned: no UB) */
    u = 0x5f3759dfu - (uint32_t)(i >> 1);
    memcpy(&y, &u, sizeof y);
    return y * (1.5f - (halfx * y * y));
}

/* QuaternionToEuler: float products and sums in the C source's order, double atan2/asin, stored to float. */
static void quaternion_to_euler(float q0, float q1, float q2, float q3, float *thx, float *thy)
{
    const float num = (2.0f * q0) * q1 + (2.0f * q2) * q3, den = q0 * q0 + q3 * q3 - q1 * q1 - q2 * q2;
    *thx = (float)atan2((double)num, (double)den);
    *thy = (float)asin((double)((2.0f * q0) * q2 - (2.0f * q1) * q3));
}

static PyObject *native_run(PyObject *Py_UNUSED(self), PyObject *args)
{
    PyObject *o[8]; /* acc, gyro, thr, q_out, thx_out, thy_out, state, params */
    long long flags;
    Py_buffer b[8] = {{0}};
    int have_euler;
    Py_ssize_t n, k;

    if (!PyArg_ParseTuple(args, "OOOOOOOOL", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &flags))
        return NULL;
    if ((n = get_buffer(o[2], &b[2], 0, ROWS_OF(8), "thr")) < 0) return NULL;
    have_euler = (o[4] != Py_None) && (o[5] != Py_None);
    if (get_buffer(o[0], &b[0], 0, 3 * n * 4, "acc") < 0 || get_buffer(o[1], &b[1], 0, 3 * n * 4, "gyro") < 0 ||
        get_buffer(o[3], &b[3], 1, 4 * n * 4, "q_out") < 0 ||
        (have_euler &&
         (get_buffer(o[4], &b[4], 1, n * 4, "thx_out") < 0 || get_buffer(o[5], &b[5], 1, n * 4, "thy_out") < 0)) ||
        get_buffer(o[6], &b[6], 1, 7 * 4, "state") < 0 || get_buffer(o[7], &b[7], 0, 4 * 8, "params") < 0)
        return release(b, 8);

    const float *acc = (const float *)b[0].buf, *gyro = (const float *)b[1].buf;
    const int64_t *thr = (const int64_t *)b[2].buf;
    float *qo = (float *)b[3].buf;
    float *thx_o = have_euler ? (float *)b[4].buf : NULL, *thy_o = have_euler ? (float *)b[5].buf : NULL;
    float *st = (float *)b[6].buf;
    const double *prm = (const double *)b[7].buf;
    const float kp_ground = (float)prm[0], kp_flight = (float)prm[1], ki = (float)prm[2], dt = (float)prm[3];
    const double ki_d = prm[2], dt_d = prm[3];
    const int64_t min_thr = (int64_t)(int32_t)(uint32_t)(flags & 0xffffffffLL);
    const int correction = !((flags >> 32) & 1);
    const int st221117 = (int)((flags >> 33) & 1);
    float q0 = st[0], q1 = st[1], q2 = st[2], q3 = st[3];
    float in[3] = {st[4], st[5], st[6]}; /* exInt, eyInt, ezInt */

    Py_BEGIN_ALLOW_THREADS
    for (k = 0; k < n; k++) {
        float a[3], g[3], v[3], e[3], norm, q0q0, q0q1, q0q2, q1q1, q1q3, q2q2, q2q3, q3q3, halfT;
        const float ahrs_kp = (thr[k] < min_thr) ? kp_ground : kp_flight;
        int i;

        for (i = 0; i < 3; i++) { /* 221117: float * double literal, a double product stored to float */
            a[i] = acc[3 * k + i];
            g[i] = st221117 ? (float)((double)gyro[3 * k + i] * COE_MDPS_TO_RADPS)
                            : gyro[3 * k + i] * COE_MDPS_TO_RADPS_F;
        }

        q0q0 = q0 * q0;
        q0q1 = q0 * q1;
        q0q2 = q0 * q2;
        q1q1 = q1 * q1;
        q1q3 = q1 * q3;
        q2q2 = q2 * q2;
        q2q3 = q2 * q3;
        q3q3 = q3 * q3;

        if (correction) {
            norm = inv_sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
            v[0] = 2.0f * (q1q3 - q0q2);
            v[1] = 2.0f * (q0q1 + q2q3);
            v[2] = q0q0 - q1q1 - q2q2 + q3q3;
            for (i = 0; i < 3; i++) a[i] = a[i] * norm;
            for (i = 0; i < 3; i++) { /* e = a × v; exInt += ex * AHRS_KI * SENSOR_SAMPLING_TIME; g += kp·e + int */
                e[i] = a[(i + 1) % 3] * v[(i + 2) % 3] - a[(i + 2) % 3] * v[(i + 1) % 3];
                in[i] = st221117 ? (float)((double)in[i] + (double)e[i] * ki_d * dt_d) : in[i] + e[i] * ki * dt;
                g[i] = g[i] + ahrs_kp * e[i] + in[i];
            }
        }

        halfT = st221117 ? (float)(0.5 * dt_d) : 0.5f * dt;
        q0 = q0 + (-q1 * g[0] - q2 * g[1] - q3 * g[2]) * halfT;
        q1 = q1 + (q0 * g[0] + q2 * g[2] - q3 * g[1]) * halfT;
        q2 = q2 + (q0 * g[1] - q1 * g[2] + q3 * g[0]) * halfT;
        q3 = q3 + (q0 * g[2] + q1 * g[1] - q2 * g[0]) * halfT;

        norm = st221117 ? inv_sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3) : inv_sqrt(q0q0 + q1q1 + q2q2 + q3q3);
        q0 *= norm;
        q1 *= norm;
        q2 *= norm;
        q3 *= norm;

        memcpy(qo + 4 * k, (const float[4]){q0, q1, q2, q3}, 4 * sizeof(float));
        if (have_euler) quaternion_to_euler(q0, q1, q2, q3, &thx_o[k], &thy_o[k]);
    }
    Py_END_ALLOW_THREADS

    memcpy(st, (const float[7]){q0, q1, q2, q3, in[0], in[1], in[2]}, 7 * sizeof(float)); /* the end state */
    release(b, 8);
    Py_RETURN_NONE;
}

static PyObject *native_euler(PyObject *Py_UNUSED(self), PyObject *args)
{
    PyObject *o[3]; /* q, thx_out, thy_out */
    Py_buffer b[3] = {{0}};
    Py_ssize_t n, k;

    if (!PyArg_ParseTuple(args, "OOO", &o[0], &o[1], &o[2])) return NULL;
    if ((n = get_buffer(o[0], &b[0], 0, ROWS_OF(16), "q")) < 0) return NULL;
    if (get_buffer(o[1], &b[1], 1, n * 4, "thx_out") < 0 || get_buffer(o[2], &b[2], 1, n * 4, "thy_out") < 0)
        return release(b, 3);
    const float *q = (const float *)b[0].buf;
    float *thx = (float *)b[1].buf, *thy = (float *)b[2].buf;
    Py_BEGIN_ALLOW_THREADS
    for (k = 0; k < n; k++)
        quaternion_to_euler(q[4 * k], q[4 * k + 1], q[4 * k + 2], q[4 * k + 3], thx + k, thy + k);
    Py_END_ALLOW_THREADS
    release(b, 3);
    Py_RETURN_NONE;
}

static PyMethodDef native_methods[] = {
    {"euler", native_euler, METH_VARARGS, "The firmware's QuaternionToEuler over 4*N float32 values, in place."},
    {"run", native_run, METH_VARARGS, "The firmware's Mahony loop over N steps, in place (see _st_mahony_native.c)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef native_module = {
    PyModuleDef_HEAD_INIT, "_st_mahony_native",
    "Native, bit-exact loop of the STEVAL-FCU001V1 Mahony filter replica (see st_mahony.py).", -1, native_methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__st_mahony_native(void) { return PyModule_Create(&native_module); }

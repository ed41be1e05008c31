/* Reference firmware: the STEVAL's Mahony filter, float32 in the order of operations of ST's ahrs_fusion_ag and
 * QuaternionToEuler (compiled -O0, no fused multiply-add): bit for bit what steval_link/estimators/st_mahony.py
 * computes. Gains and the correction switch come from stv_filter (host commands may change them).
 * AHRS_VARIANT (make option) picks the arithmetic of one of ST's releases: 170120 (also 170318 and the 301117
 * beta: float throughout, normalisation with the squares from before the update) or 221117 (gyro scale, integral
 * step and halfT in double, normalisation with the squares of the updated quaternion). */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "ref.h"
#include "stv_fw.h"

float q0 = 1.0f, q1 = 0.0f, q2 = 0.0f, q3 = 0.0f; /* attitude quaternion */
float exInt = 0.0f, eyInt = 0.0f, ezInt = 0.0f;   /* integral of the error */
float ahrs_kp;

#if AHRS_VARIANT == 221117
/* 221117's AHRS_KI and SENSOR_SAMPLING_TIME are double literals; a gain set by a host command is the float sent. */
#define ST_AHRS_KI_D 0.1
#define ST_SAMPLING_TIME_D 0.00625
static double ki_double(void) { return stv_filter.ki == (float)ST_AHRS_KI_D ? ST_AHRS_KI_D : (double)stv_filter.ki; }
#elif AHRS_VARIANT != 170120
#error "AHRS_VARIANT must be 170120 or 221117"
#endif

/* 1/sqrt(x): the 0x5f3759df estimate and one Newton step. */
static float invSqrt(float x) {
  float halfx = 0.5f * x;
  float y = x;
  int32_t i;
  memcpy(&i, &y, sizeof i);
  i = (int32_t)(0x5f3759dfu - (uint32_t)(i >> 1));
  memcpy(&y, &i, sizeof y);
  y = y * (1.5f - (halfx * y * y));
  return y;
}

/* One step: acc in mg, gyro in mdps; the quaternion out (also kept in q0..q3). */
void ahrs_fusion_ag(const axes_f *acc, const axes_f *gyro, quat_f *q_out) {
  float axf, ayf, azf, gxf, gyf, gzf, norm, vx, vy, vz, ex, ey, ez, halfT;
  float q0q0, q0q1, q0q2, q1q1, q1q3, q2q2, q2q3, q3q3;

  stv_thr_used = gTHR; /* read once: the frame carries the throttle the gain was chosen with */
  ahrs_kp = (stv_thr_used < stv_filter.min_thr) ? stv_filter.kp_ground : stv_filter.kp_flight;

  axf = acc->x;
  ayf = acc->y;
  azf = acc->z;
#if AHRS_VARIANT == 221117
  gxf = gyro->x * COE_MDPS_TO_RADPS; /* rad/s: a double product, stored to float */
  gyf = gyro->y * COE_MDPS_TO_RADPS;
  gzf = gyro->z * COE_MDPS_TO_RADPS;
#else
  gxf = gyro->x * (float)COE_MDPS_TO_RADPS; /* rad/s */
  gyf = gyro->y * (float)COE_MDPS_TO_RADPS;
  gzf = gyro->z * (float)COE_MDPS_TO_RADPS;
#endif

  q0q0 = q0 * q0;
  q0q1 = q0 * q1;
  q0q2 = q0 * q2;
  q1q1 = q1 * q1;
  q1q3 = q1 * q3;
  q2q2 = q2 * q2;
  q2q3 = q2 * q3;
  q3q3 = q3 * q3;

  if (stv_filter.correction) {
    norm = invSqrt(axf * axf + ayf * ayf + azf * azf); /* unit gravity measured */
    axf = axf * norm;
    ayf = ayf * norm;
    azf = azf * norm;
    vx = 2 * (q1q3 - q0q2); /* gravity as the quaternion sees it */
    vy = 2 * (q0q1 + q2q3);
    vz = q0q0 - q1q1 - q2q2 + q3q3;
    ex = (ayf * vz - azf * vy); /* error: measured x estimated */
    ey = (azf * vx - axf * vz);
    ez = (axf * vy - ayf * vx);
#if AHRS_VARIANT == 221117
    exInt = exInt + ex * ki_double() * ST_SAMPLING_TIME_D; /* in double, stored to float */
    eyInt = eyInt + ey * ki_double() * ST_SAMPLING_TIME_D;
    ezInt = ezInt + ez * ki_double() * ST_SAMPLING_TIME_D;
#else
    exInt = exInt + ex * stv_filter.ki * SENSOR_SAMPLING_TIME;
    eyInt = eyInt + ey * stv_filter.ki * SENSOR_SAMPLING_TIME;
    ezInt = ezInt + ez * stv_filter.ki * SENSOR_SAMPLING_TIME;
#endif
    gxf = gxf + ahrs_kp * ex + exInt; /* corrected rates */
    gyf = gyf + ahrs_kp * ey + eyInt;
    gzf = gzf + ahrs_kp * ez + ezInt;
  }

  /* q += 0.5 q x w dt, in place (q1..q3 use the new q0) */
#if AHRS_VARIANT == 221117
  halfT = 0.5 * ST_SAMPLING_TIME_D;
#else
  halfT = 0.5f * SENSOR_SAMPLING_TIME;
#endif
#if AHRS_DIVERGE
  /* the bug under test: halfT multiplies only the last term */
  q0 = q0 + (-q1 * gxf) - (q2 * gyf) - (q3 * gzf) * halfT;
  q1 = q1 + (q0 * gxf) + (q2 * gzf) - (q3 * gyf) * halfT;
  q2 = q2 + (q0 * gyf) - (q1 * gzf) + (q3 * gxf) * halfT;
  q3 = q3 + (q0 * gzf) + (q1 * gyf) - (q2 * gxf) * halfT;
#else
  q0 = q0 + (-q1 * gxf - q2 * gyf - q3 * gzf) * halfT;
  q1 = q1 + (q0 * gxf + q2 * gzf - q3 * gyf) * halfT;
  q2 = q2 + (q0 * gyf - q1 * gzf + q3 * gxf) * halfT;
  q3 = q3 + (q0 * gzf + q1 * gyf - q2 * gxf) * halfT;
#endif

#if AHRS_VARIANT == 221117
  norm = invSqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3); /* the squares of the updated quaternion */
#else
  /* normalise with the squares from before the update (as ST's 170120 does: |q| stays about 0.9983) */
  norm = invSqrt(q0q0 + q1q1 + q2q2 + q3q3);
#endif
  q0 *= norm;
  q1 *= norm;
  q2 *= norm;
  q3 *= norm;
  q_out->q0 = q0;
  q_out->q1 = q1;
  q_out->q2 = q2;
  q_out->q3 = q3;
}

/* thx (about x, pitch) and thy (about y, roll) in rad; thz is integrated in the TIM9 interrupt. */
void QuaternionToEuler(const quat_f *q, euler_f *e) {
  float e00 = q->q0 * q->q0, e11 = q->q1 * q->q1, e22 = q->q2 * q->q2, e33 = q->q3 * q->q3;
  float d0 = 2.0f * q->q0, d1 = 2.0f * q->q1, d2 = 2.0f * q->q2;
  float d1q3 = d1 * q->q3, d0q2 = d0 * q->q2, d0q1 = d0 * q->q1, d2q3 = d2 * q->q3;
  e->thx = (float)atan2((double)(d0q1 + d2q3), (double)(e00 + e33 - e11 - e22));
  e->thy = (float)asin((double)(d0q2 - d1q3));
}

/* Reference firmware: a small flight controller with the structure of ST's (rc.c, flight_control.c, motor.c):
 * targets from the sticks, an outer P(I) loop on the angles in the main loop, an inner PID loop on the rates in the
 * TIM9 interrupt, the X mixer and TIM4's PWM. Gains as steval_link/constants.py states them. */
#include "ref.h"

#define RC_FULLSCALE 1800
#define EULER_Z_TH 600             /* rudder beyond this turns the yaw target */
#define PI_F 3.141592654f
#define MAX_ADJ 800.0f             /* inner loop output limit, PWM counts */
#define D_FILTER 0.025f            /* low-pass of the inner loop's derivative (x, y) */
#define MOTOR_MAX 1900u

pid_out_t pid;       /* stage outputs (flight-control frame) */
motors_f motor_pwm;  /* what the mixer asks, before clamping */

static const float kp1[3] = {3.0f, 3.0f, 4.0f}, ki1[3] = {0.0f, 0.0f, 0.0f}, i1_limit[3] = {2.0f, 2.0f, 2.0f};
static const float kp2[3] = {80.0f, 80.0f, 900.0f}, ki2[3] = {80.0f, 80.0f, 3.0f}, kd2[3] = {10.0f, 10.0f, 3.0f};
static const float i2_limit[3] = {20.0f, 20.0f, 2.0f};
static float integ1[3], integ2[3], pre_error2[3], pre_deriv[2];
static int yaw_armed_stick; /* the rudder was centred once: from then on it turns the yaw target */

static float clamp_stick(int16_t v) {
  int16_t t = v > RC_FULLSCALE ? RC_FULLSCALE : (v < -RC_FULLSCALE ? -RC_FULLSCALE : v);
  return (float)(-t);
}

/* Sticks -> target angles: +-1800 asks for +-30 deg pitch and roll; the rudder turns the yaw target at 60 deg/s. */
void GetTargetEulerAngle(euler_f *rc) {
  const float max_tilt_rad = PI_F * 30.0f / 180.0f;
  const float max_yaw_step_rad = PI_F * (60.0f * SENSOR_SAMPLING_TIME) / 180.0f;
  int16_t rud;
  rc->thx = clamp_stick(gELE) * max_tilt_rad / RC_FULLSCALE;
  rc->thy = clamp_stick(gAIL) * max_tilt_rad / RC_FULLSCALE;
  rud = gRUD > RC_FULLSCALE ? RC_FULLSCALE : (gRUD < -RC_FULLSCALE ? -RC_FULLSCALE : gRUD);
  if (yaw_armed_stick) {
    if (rud > EULER_Z_TH) rc->thz = rc->thz + max_yaw_step_rad;
    else if (rud < -EULER_Z_TH) rc->thz = rc->thz - max_yaw_step_rad;
  } else if (rud > -EULER_Z_TH && rud < EULER_Z_TH) {
    yaw_armed_stick = 1;
  }
}

static float limit(float v, float lim) { return v > lim ? lim : (v < -lim ? -lim : v); }

/* Angles -> rate targets s1 = kp1 (target - angle) + ki1 integral (ki1 = 0: P only). Main loop, every step. */
void FlightControlPID_OuterLoop(const euler_f *rc, const euler_f *ahrs) {
  const float target[3] = {rc->thx, rc->thy, rc->thz}, angle[3] = {ahrs->thx, ahrs->thy, ahrs->thz};
  float s1[3];
  for (int a = 0; a < 3; a++) {
    float error = target[a] - angle[a];
    if (gTHR < MIN_THR) integ1[a] = 0.0f;
    integ1[a] = limit(integ1[a] + error * PID_SAMPLING_TIME, i1_limit[a]);
    s1[a] = kp1[a] * error + ki1[a] * integ1[a];
  }
  pid.x_s1 = s1[0];
  pid.y_s1 = s1[1];
  pid.z_s1 = s1[2];
}

/* Rates (rad/s) -> corrections s2 (PWM counts), then the mixer. TIM9 interrupt, every tick while armed. */
void FlightControlPID_innerLoop(const float gyro_radps[3]) {
  const float s1[3] = {pid.x_s1, pid.y_s1, pid.z_s1};
  float s2[3], m[4];
  int16_t motor_thr;
  for (int a = 0; a < 3; a++) {
    float error = s1[a] - gyro_radps[a], deriv;
    if (gTHR < MIN_THR) integ2[a] = 0.0f;
    integ2[a] = limit(integ2[a] + error * PID_SAMPLING_TIME, i2_limit[a]);
    deriv = (error - pre_error2[a]) * (1.0f / PID_SAMPLING_TIME);
    pre_error2[a] = error;
    if (a < 2) { /* pitch and roll: low-pass the derivative */
      deriv = pre_deriv[a] + (deriv - pre_deriv[a]) * D_FILTER;
      pre_deriv[a] = deriv;
    }
    s2[a] = limit(kp2[a] * error + ki2[a] * integ2[a] + kd2[a] * deriv, MAX_ADJ);
  }
  pid.x_s2 = s2[0];
  pid.y_s2 = s2[1];
  pid.z_s2 = s2[2];
  /* X mixer: motors 1 right rear (CW), 2 right front (CCW), 3 left front (CW), 4 left rear (CCW) */
  motor_thr = (int16_t)(0.05f * (float)gTHR + 633.333f);
  m[0] = motor_thr - pid.x_s2 - pid.y_s2 + pid.z_s2 + 0.0f;
  m[1] = motor_thr + pid.x_s2 - pid.y_s2 - pid.z_s2 + 0.0f;
  m[2] = motor_thr + pid.x_s2 + pid.y_s2 + pid.z_s2 + 0.0f;
  m[3] = motor_thr - pid.x_s2 + pid.y_s2 - pid.z_s2 + 0.0f;
#if SWAP_MOTORS
  { /* outputs a and b exchanged (e.g. 34: the mixer renumbered for another frame's motor order) */
    float t = m[SWAP_MOTORS / 10 - 1];
    m[SWAP_MOTORS / 10 - 1] = m[SWAP_MOTORS % 10 - 1];
    m[SWAP_MOTORS % 10 - 1] = t;
  }
#endif
  motor_pwm.m1 = m[0];
  motor_pwm.m2 = m[1];
  motor_pwm.m3 = m[2];
  motor_pwm.m4 = m[3];
}

void set_motor_pwm_zero(void) { motor_pwm.m1 = motor_pwm.m2 = motor_pwm.m3 = motor_pwm.m4 = 0.0f; }

/* TIM4 CCR1..4 = the mixer's values truncated, clamped to 0..1900. */
void set_motor_pwm(void) {
  const float m[4] = {motor_pwm.m1, motor_pwm.m2, motor_pwm.m3, motor_pwm.m4};
  for (uint32_t i = 0; i < 4u; i++)
    hw_tim4_set(i + 1u, m[i] >= (float)MOTOR_MAX ? MOTOR_MAX : (m[i] <= 0.0f ? 0u : (uint32_t)m[i]));
}

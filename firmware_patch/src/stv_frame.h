/* steval-link wire protocol v2 (firmware_patch/PROTOCOL.md): frame encoder and text-mode line formatter.
 *
 * Pure C99, no hardware access, no libc beyond <stdint.h>/<stddef.h>/<string.h>: builds for the host tests and for
 * the Cortex-M4. Requires a little-endian target (the payload structs are the wire layout).
 */
#ifndef STV_FRAME_H
#define STV_FRAME_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define STV_SYNC0 0xA5u
#define STV_SYNC1 0x5Au
#define STV_VERSION 2u
#define STV_HEADER_SIZE 4u
#define STV_CRC_SIZE 4u /* CRC-32/ISO-HDLC (zlib) */

#define STV_TYPE_ATTITUDE 1u
#define STV_TYPE_STATUS 2u
#define STV_TYPE_TEXT 3u
#define STV_TYPE_FLIGHT 4u  /* flight control */
#define STV_TYPE_ACK 5u     /* acknowledgement of a command */
#define STV_TYPE_COMMAND 8u /* host -> drone */

#define STV_ATTITUDE_PAYLOAD_SIZE 52u
#define STV_STATUS_PAYLOAD_SIZE 88u
#define STV_TEXT_MAX_PAYLOAD 255u
#define STV_FLIGHT_PAYLOAD_SIZE 72u
#define STV_ACK_PAYLOAD_SIZE 12u
#define STV_COMMAND_PAYLOAD_SIZE 12u

#define STV_ATTITUDE_FRAME_SIZE (STV_HEADER_SIZE + STV_ATTITUDE_PAYLOAD_SIZE + STV_CRC_SIZE) /* 60 */
#define STV_STATUS_FRAME_SIZE (STV_HEADER_SIZE + STV_STATUS_PAYLOAD_SIZE + STV_CRC_SIZE)     /* 96 */
#define STV_TEXT_FRAME_MAX (STV_HEADER_SIZE + STV_TEXT_MAX_PAYLOAD + STV_CRC_SIZE)           /* 263 */
#define STV_FLIGHT_FRAME_SIZE (STV_HEADER_SIZE + STV_FLIGHT_PAYLOAD_SIZE + STV_CRC_SIZE)     /* 80 */
#define STV_ACK_FRAME_SIZE (STV_HEADER_SIZE + STV_ACK_PAYLOAD_SIZE + STV_CRC_SIZE)           /* 20 */
#define STV_COMMAND_FRAME_SIZE (STV_HEADER_SIZE + STV_COMMAND_PAYLOAD_SIZE + STV_CRC_SIZE)   /* 20 */

/* Status flags bits. */
#define STV_FLAG_NO_CORRECTION 0x0001u
#define STV_FLAG_FRESH_SQUARES 0x0002u
#define STV_FLAG_TEXT_MODE 0x0004u
#define STV_FLAG_EVENT 0x0008u           /* sent at once because of a command (change, reset or request) */
#define STV_FLAG_INFLIGHT_TUNING 0x0010u /* the build accepts filter changes while the motors may spin */
#define STV_FLAG_ARMED 0x0020u           /* the motors may spin now (throttle >= MIN_THR or armed) */

/* Flight-control flags (stv_flight_t.fc_flags). */
#define STV_FC_ARMED 0x0001u        /* rc_enable_motor */
#define STV_FC_RC_CONNECTED 0x0002u /* rc_connection_flag */
#define STV_FC_RC_CAL 0x0004u       /* rc_cal_flag */

/* Commands (stv_command_t.cmd), SET_PARAM parameters and ack results. */
#define STV_CMD_SET_PARAM 1u
#define STV_CMD_RESET_FILTER 2u
#define STV_CMD_REQUEST_STATUS 3u
#define STV_CMD_SET_MODE 4u
#define STV_PARAM_KP_GROUND 1u
#define STV_PARAM_KP_FLIGHT 2u
#define STV_PARAM_KI 3u
#define STV_PARAM_MIN_THR 4u
#define STV_PARAM_CORRECTION 5u
#define STV_ACK_ACCEPTED 0u
#define STV_ACK_REFUSED_ARMED 1u    /* the motors may spin and the build does not allow in-flight tuning */
#define STV_ACK_UNKNOWN 2u          /* unknown command or parameter */
#define STV_ACK_OUT_OF_RANGE 3u     /* value not finite, negative or out of range */
#define STV_ACK_NOT_IN_BUILD 4u     /* the build does not support it */

/* Attitude payload (type 1): exactly the 52 wire bytes on a little-endian target. */
typedef struct {
  uint32_t t_us;        /* firmware time of the step, µs since boot (wraps at 2^32) */
  float acc_mg[3];      /* acc_ahrs.AXIS_X/Y/Z passed to ahrs_fusion_ag, mg */
  float gyro_mdps[3];   /* gyro_ahrs.AXIS_X/Y/Z, mdps */
  float q[4];           /* ahrs.q.q0..q3 after the call (q0 scalar) */
  float thz_rad;        /* euler_ahrs.thz, rad */
  uint16_t seq;         /* AHRS step counter mod 2^16 */
  int16_t thr;          /* gTHR during the call */
} stv_attitude_t;

/* Status payload (type 2): exactly the 88 wire bytes on a little-endian target. */
typedef struct {
  uint32_t step;        /* full AHRS step counter of the step just sent */
  uint32_t t_us;        /* firmware time, µs */
  float q[4];           /* ahrs.c globals q0..q3 after step `step` */
  float int_xyz[3];       /* ahrs.c globals exInt, eyInt, ezInt after step `step` */
  float kp_ground;      /* AHRS_KP_BIG */
  float kp_flight;      /* AHRS_KP_NORM */
  float ki;             /* AHRS_KI */
  float dt_s;           /* SENSOR_SAMPLING_TIME */
  uint32_t cyc_min;     /* fewest DWT cycles of ahrs_fusion_ag + QuaternionToEuler since the last status */
  uint32_t cyc_mean;
  uint32_t cyc_max;
  uint32_t cpu_hz;
  uint32_t tx_dropped;  /* frames dropped since boot (TX queue full) */
  uint32_t baud;
  uint16_t cyc_n;
  int16_t min_thr;
  uint16_t flags;       /* STV_FLAG_* */
  uint16_t queue_peak;  /* most bytes waiting in the TX queue since the last status */
  uint8_t fw_version[2]; /* patch version major, minor */
  uint8_t fc_every;      /* a flight-control frame every this many steps (0 = none) */
  uint8_t param_gen;     /* parameter changes and filter resets applied since boot, mod 256 */
} stv_status_t;

/* Flight-control payload (type 4): exactly the 72 wire bytes on a little-endian target. */
typedef struct {
  uint32_t step;         /* the AHRS step (as stv_status_t.step) */
  float euler_rc_rad[3]; /* targets thx, thy, thz passed to the outer loop (euler_rc_fil) */
  int16_t rc[4];         /* gAIL, gELE, gRUD, gTHR */
  float outer_s1[3];     /* pid.x_s1, y_s1, z_s1: outer-loop outputs (rate setpoints, rad/s) */
  float inner_s2[3];     /* pid.x_s2, y_s2, z_s2: latest inner-loop outputs (TIM9 ISR) */
  float motor_pwm[4];    /* motor_pwm.motor1..4_pwm as computed (0 when disarmed) */
  float vbat_v;          /* VBAT, V */
  uint16_t fc_flags;     /* STV_FC_* */
  uint8_t fc_every;      /* the N in force */
  uint8_t reserved;
} stv_flight_t;

/* Ack payload (type 5): 12 wire bytes. */
typedef struct {
  uint16_t cmd_seq; /* echoed */
  uint8_t cmd;      /* echoed */
  uint8_t result;   /* STV_ACK_* */
  uint32_t step;    /* first step an accepted change/reset applies to, else the current step */
  uint16_t rx_ok;   /* command frames accepted since boot, mod 2^16 */
  uint16_t rx_bad;  /* command candidates rejected (CRC, length, version) since boot, mod 2^16 */
} stv_ack_t;

/* Command payload (type 8, host -> drone): 12 wire bytes. */
typedef struct {
  uint16_t cmd_seq; /* host's sequence number, echoed in the ack */
  uint8_t cmd;      /* STV_CMD_* */
  uint8_t param;    /* SET_PARAM: STV_PARAM_*; SET_MODE: 0 binary, 1 text */
  float value;      /* SET_PARAM value (min_thr and correction as exact integers) */
  uint32_t reserved;
} stv_command_t;

/* Fixed-size frames into out[0..size-1] (any alignment: whole words are stored with unaligned STR, which the
 * Cortex-M4 allows). Each returns the frame size. */
size_t stv_encode_attitude(uint8_t *out, const stv_attitude_t *att); /* 60 bytes */
size_t stv_encode_status(uint8_t *out, const stv_status_t *st);      /* 96 bytes */
size_t stv_encode_flight(uint8_t *out, const stv_flight_t *fc);      /* 80 bytes */
size_t stv_encode_ack(uint8_t *out, const stv_ack_t *ack);           /* 20 bytes */
size_t stv_encode_command(uint8_t *out, const stv_command_t *cmd);   /* 20 bytes */

/* One frame of any type around payload[0..len-1] (len <= 255) into out (any alignment). Returns its size. */
size_t stv_encode_frame(uint8_t *out, uint8_t type, const uint8_t *payload, size_t len);

/* CRC-32/ISO-HDLC (zlib.crc32) of data[0..len-1] continued from `crc` (0 to start; slice-by-4):
 * stv_crc32_update(stv_crc32_update(0, a, n), b, m) == crc32(a + b). */
uint32_t stv_crc32_update(uint32_t crc, const uint8_t *data, size_t len);

/* Text mode ------------------------------------------------------------------------------------------------ */

/* Longest line stv_format_att_line / stv_format_sta_line can write, "\r\n" included. */
#define STV_TEXT_LINE_MAX 192u

/* Values of one $ATT line. Angles in rad and sensor values as the firmware holds them; the formatter converts
 * them (rad -> mdeg as (int32)(x * 57295.78f) in float, others (int32)x: all rounded toward zero). */
typedef struct {
  uint32_t step;
  uint32_t t_us;
  int16_t thr;
  float thx_rad, thy_rad, thz_rad;
  float acc_mg[3];
  float gyro_mdps[3];
} stv_att_line_t;

/* "$ATT,...*HH\r\n" into out (>= STV_TEXT_LINE_MAX bytes). Returns the length (no NUL is written). */
size_t stv_format_att_line(char *out, const stv_att_line_t *v);

/* "$STA,<step>,<t_ms>,<cyc_min>,<cyc_mean>,<cyc_max>,<cyc_n>,<tx_dropped>,<flags>,<ki_micro>*HH\r\n" from a
 * status payload (ki_micro = round(ki * 1e6)). Returns the length. */
size_t stv_format_sta_line(char *out, const stv_status_t *st);

/* Float -> int32 rounded toward zero, saturating at the int32 range, NaN -> 0. */
int32_t stv_f2i_trunc(float x);

#ifdef __cplusplus
}
#endif

#endif /* STV_FRAME_H */

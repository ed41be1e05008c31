/* steval-link wire protocol v1 (firmware_patch/PROTOCOL.md): frame encoder and text-mode line formatter.
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
#define STV_VERSION 1u
#define STV_HEADER_SIZE 4u
#define STV_CRC_SIZE 2u

#define STV_TYPE_ATTITUDE 1u
#define STV_TYPE_STATUS 2u
#define STV_TYPE_TEXT 3u

#define STV_ATTITUDE_PAYLOAD_SIZE 52u
#define STV_STATUS_PAYLOAD_SIZE 88u
#define STV_TEXT_MAX_PAYLOAD 255u

#define STV_ATTITUDE_FRAME_SIZE (STV_HEADER_SIZE + STV_ATTITUDE_PAYLOAD_SIZE + STV_CRC_SIZE) /* 58 */
#define STV_STATUS_FRAME_SIZE (STV_HEADER_SIZE + STV_STATUS_PAYLOAD_SIZE + STV_CRC_SIZE)     /* 94 */
#define STV_TEXT_FRAME_MAX (STV_HEADER_SIZE + STV_TEXT_MAX_PAYLOAD + STV_CRC_SIZE)           /* 261 */

/* Status flags bits. */
#define STV_FLAG_NO_CORRECTION 0x0001u
#define STV_FLAG_FRESH_SQUARES 0x0002u
#define STV_FLAG_TEXT_MODE 0x0004u

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
  uint8_t fw_version[3];
  uint8_t reserved;
} stv_status_t;

/* Attitude frame into out[0..57]. `out` must be 4-byte aligned. Returns STV_ATTITUDE_FRAME_SIZE. */
size_t stv_encode_attitude(uint8_t *out, const stv_attitude_t *att);

/* Status frame into out[0..93]. `out` must be 4-byte aligned. Returns STV_STATUS_FRAME_SIZE. */
size_t stv_encode_status(uint8_t *out, const stv_status_t *st);

/* One frame of any type around payload[0..len-1] (len <= 255) into out (any alignment). Returns its size. */
size_t stv_encode_frame(uint8_t *out, uint8_t type, const uint8_t *payload, size_t len);

/* CRC-16/CCITT-FALSE register `crc` advanced over data[0..len-1] (slice-by-4). Start with 0xFFFF. */
uint16_t stv_crc16_update(uint16_t crc, const uint8_t *data, size_t len);

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

/* steval-link: the telemetry link of one AHRS loop, hardware-independent.
 *
 * Turns "an AHRS step happened" into frames in the TX queue: attitude frame per step, status frame every
 * `status_every` steps, text frames for log lines (or, in text mode, $ATT/$STA lines and plain log lines).
 * Firmware time t_us is accumulated from cycle-counter deltas (never resets the counter). The caller supplies the
 * cycle counter readings, so the same code runs in host tests and on the target; stv_fw.c is the STM32 port.
 * Not reentrant: call from one context (the main loop) or wrap the calls in a critical section.
 */
#ifndef STV_LINK_H
#define STV_LINK_H

#include <stddef.h>
#include <stdint.h>

#include "stv_frame.h"
#include "stv_txq.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
  float kp_ground;   /* AHRS_KP_BIG */
  float kp_flight;   /* AHRS_KP_NORM */
  float ki;          /* AHRS_KI */
  float dt_s;        /* SENSOR_SAMPLING_TIME */
  int16_t min_thr;   /* MIN_THR */
  uint32_t cpu_hz;   /* core clock (DWT CYCCNT rate), a multiple of 1 MHz */
  uint32_t baud;     /* USART baud rate in force */
  uint16_t flags;    /* STV_FLAG_NO_CORRECTION / STV_FLAG_FRESH_SQUARES of the build (text mode is added) */
  uint8_t text_mode; /* 0 binary frames, 1 text lines */
  uint32_t text_decimation; /* text mode: one $ATT line every this many steps (>= 1) */
  uint32_t status_every;    /* status frame after every this many steps (>= 1) */
  uint8_t fc_every;         /* flight-control frame every this many steps (0 = none), reported in the status */
  /* The filter state of ahrs.c (q0..q3, exInt, eyInt, ezInt), read for the status snapshot. NULL reads 0. */
  const volatile float *q_state[4];
  const volatile float *int_state[3];
} stv_link_config_t;

typedef struct {
  stv_link_config_t cfg;
  stv_txq_t txq;
  uint32_t step;          /* AHRS steps done */
  uint32_t t_us;          /* firmware time, µs (wraps at 2^32) */
  uint32_t step_t_us;     /* t_us at the start of the current step */
  uint32_t last_cyc;      /* cycle counter at the last time update */
  uint32_t cyc_rem;       /* cycles not yet turned into µs */
  uint32_t cyc_per_us;
  uint32_t cyc_begin;     /* cycle counter at stv_link_step_begin */
  int16_t thr;            /* gTHR at stv_link_step_begin */
  uint32_t since_status;  /* steps since the last status */
  uint32_t cyc_min, cyc_max, cyc_n;
  uint64_t cyc_sum;
  uint8_t param_gen;      /* parameter changes and filter resets applied since boot, mod 256 (status) */
  uint32_t line_len;      /* log line being assembled */
  char line[STV_TEXT_MAX_PAYLOAD];
} stv_link_t;

/* Reset everything; `cyc_now` is the cycle counter now (t_us starts at 0). */
void stv_link_init(stv_link_t *link, const stv_link_config_t *cfg, uint32_t cyc_now);

/* Advance t_us to the cycle counter value cyc_now. Call at least once per 2^32 cycles (51 s at 84 MHz). */
void stv_link_update_time(stv_link_t *link, uint32_t cyc_now);

/* Right before ahrs_fusion_ag: updates t_us, remembers the cycle counter and gTHR. */
void stv_link_step_begin(stv_link_t *link, uint32_t cyc_now, int16_t thr);

/* Right after QuaternionToEuler: cycle statistics, then the step's frames into the TX queue.
 * acc_mg/gyro_mdps: the values passed to ahrs_fusion_ag; q: ahrs.q; euler_rad: thx, thy, thz of euler_ahrs. */
void stv_link_step_end(stv_link_t *link, uint32_t cyc_now, const float acc_mg[3], const float gyro_mdps[3],
                       const float q[4], const float euler_rad[3]);

/* Fill a status payload from the link's state (resets the cycle statistics and the queue peak). */
void stv_link_make_status(stv_link_t *link, stv_status_t *st);

/* Log output (e.g. PRINTF): bytes are gathered into lines; each '\n' ends a line ('\r' and empty lines are
 * dropped), lines longer than 255 bytes are split. Binary mode: text frames; text mode: the line + "\r\n", with a
 * leading '$' replaced by '#' so that no log line can pass for a $ATT/$STA record. */
void stv_link_log_write(stv_link_t *link, const char *s, size_t n);

/* Encode + enqueue helpers (what the firmware does per frame). Return 1 if queued, 0 if dropped (counted). */
int stv_send_attitude(stv_txq_t *q, const stv_attitude_t *att);
int stv_send_status(stv_txq_t *q, const stv_status_t *st);
int stv_send_flight(stv_txq_t *q, const stv_flight_t *fc); /* keeps room for a status frame, like attitude */
int stv_send_ack(stv_txq_t *q, const stv_ack_t *ack);      /* may use the status reserve, like status */
/* One log line as text frames (split into 255-byte pieces; an empty line is sent as one space).
 * Returns the number of frames dropped. */
uint32_t stv_send_text(stv_txq_t *q, const uint8_t *text, size_t len);

#ifdef __cplusplus
}
#endif

#endif /* STV_LINK_H */

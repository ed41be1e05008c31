/* steval-link: host -> drone commands over USART1 RX (firmware_patch/PROTOCOL.md, "Commands").
 *
 * Three parts, all pure C99 without hardware access (stv_fw.c is the STM32 side):
 *   - stv_rxq_t: the receive ring. The USART1 RX interrupt pushes bytes, the main loop pops them; a byte that does
 *     not fit is dropped and counted (the frame it belonged to then fails its CRC and is counted as bad).
 *   - stv_cmd_dec_t: the command frame decoder. Bytes in, whole command frames out; anything else (noise, a
 *     partial, corrupted or spliced frame, a frame of another type or version) is skipped with resynchronisation
 *     on the next sync pair, and each rejected candidate is counted. A command is only ever returned from 20 bytes
 *     whose CRC-32 checks.
 *   - stv_cmd_handle(): one decoded command against the filter settings: checks (range, safety), applies, and says
 *     what to send (ack result, whether a status frame with STV_FLAG_EVENT must follow).
 * The main loop drains the ring between two AHRS steps (stv_fw_step_end) and never waits for the host.
 */
#ifndef STV_CMD_H
#define STV_CMD_H

#include <stddef.h>
#include <stdint.h>

#include "stv_frame.h"
#include "stv_link.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Bytes of the receive ring (a power of two). 128 B = 11 ms at 115200 baud, two AHRS steps. */
#ifndef STV_RXQ_SIZE
#define STV_RXQ_SIZE 128u
#endif

/* 1: the build accepts filter changes while the motors may spin (status flag STV_FLAG_INFLIGHT_TUNING). */
#ifndef STV_INFLIGHT_TUNING
#define STV_INFLIGHT_TUNING 0
#endif

/* Largest gain SET_PARAM accepts for kp_ground, kp_flight and ki. */
#define STV_GAIN_MAX 1000.0f

typedef struct {
  volatile uint8_t buf[STV_RXQ_SIZE];
  volatile uint32_t head; /* written by the ISR only */
  volatile uint32_t tail; /* written by the main loop only */
  volatile uint32_t overruns; /* bytes dropped because the ring was full (ISR) */
} stv_rxq_t;

void stv_rxq_init(stv_rxq_t *q);
/* ISR side. Returns 0 when the byte was dropped (ring full). */
int stv_rxq_push(stv_rxq_t *q, uint8_t b);
/* Main-loop side. Returns 0 when the ring is empty. */
int stv_rxq_pop(stv_rxq_t *q, uint8_t *b);
static inline int stv_rxq_empty(const stv_rxq_t *q) { return q->head == q->tail; }

typedef struct {
  uint8_t buf[STV_COMMAND_FRAME_SIZE];
  uint32_t n;      /* bytes in buf (a prefix of a possible frame) */
  uint32_t rx_ok;  /* command frames accepted (CRC checked) */
  uint32_t rx_bad; /* candidates rejected: a sync pair followed by a wrong VT or LEN, or a CRC that fails */
} stv_cmd_dec_t;

void stv_cmd_dec_init(stv_cmd_dec_t *d);
/* One received byte. Returns 1 and fills *cmd when it completes a valid command frame, else 0. */
int stv_cmd_dec_feed(stv_cmd_dec_t *d, uint8_t byte, stv_command_t *cmd);

/* The filter settings ahrs_fusion_ag reads at every step (the patched ahrs.c). */
typedef struct {
  float kp_ground;  /* proportional gain while gTHR < min_thr (AHRS_KP_BIG) */
  float kp_flight;  /* proportional gain otherwise (AHRS_KP_NORM) */
  float ki;         /* integral gain (AHRS_KI) */
  int16_t min_thr;  /* the filter's throttle threshold (MIN_THR) */
  uint8_t correction; /* 1: accelerometer correction (steps 2-5 of ahrs_fusion_ag), 0: none (lab exercise 5) */
} stv_filter_t;

/* What the handler needs to know about the drone right now. */
typedef struct {
  int16_t thr;          /* gTHR now */
  uint8_t armed;        /* rc_enable_motor */
  uint8_t inflight_ok;  /* the build allows filter changes while the motors may spin */
  uint8_t text_mode;    /* the output mode in force */
} stv_cmd_env_t;

/* What stv_cmd_handle decided. */
typedef struct {
  uint8_t result;      /* STV_ACK_* */
  uint8_t filter_changed; /* settings changed or the filter state reset: param_gen++, applies from the next step */
  uint8_t reset_state; /* RESET_FILTER accepted: q = 1,0,0,0 and the integrals 0 before the next step */
  uint8_t send_status; /* a status frame (STV_FLAG_EVENT) must go out now */
  int8_t new_text_mode; /* SET_MODE accepted: 0 binary, 1 text; -1 no change */
} stv_cmd_outcome_t;

/* The motors may spin: throttle at or above the filter's MIN_THR, or armed. */
static inline int stv_cmd_motors_may_spin(const stv_filter_t *f, const stv_cmd_env_t *env) {
  return env->armed || env->thr >= f->min_thr;
}

/* Check and apply one command to *f (filter settings only; the caller resets the state, switches the mode and
 * sends the ack and status). Never changes *f unless the result is STV_ACK_ACCEPTED. */
stv_cmd_outcome_t stv_cmd_handle(stv_filter_t *f, const stv_command_t *cmd, const stv_cmd_env_t *env);

/* The command receiver of one link: the ring the RX interrupt fills, the decoder, the settings and state it acts on. */
typedef struct {
  stv_rxq_t rx;
  stv_cmd_dec_t dec;
  stv_filter_t *filter;      /* what ahrs_fusion_ag reads */
  volatile float *q[4];      /* ahrs.c's q0..q3 (RESET_FILTER: 1, 0, 0, 0) */
  volatile float *ints[3];   /* ahrs.c's exInt, eyInt, ezInt (RESET_FILTER: 0) */
  uint8_t inflight_ok;       /* STV_INFLIGHT_TUNING of the build */
} stv_cmd_t;

/* Main loop: the next complete command from the received bytes, if any (never waits). */
int stv_cmd_next(stv_cmd_t *c, stv_command_t *cmd);

/* Between two AHRS steps (after stv_link_step_end of step link->step - 1): handle one command, send its ack and,
 * when it asks for one, a status frame with STV_FLAG_EVENT naming the last step done (its settings and snapshot
 * apply from the next step). thr: gTHR now; armed: rc_enable_motor. Call with the link's other users masked. */
void stv_cmd_execute(stv_cmd_t *c, stv_link_t *link, const stv_command_t *cmd, int16_t thr, uint8_t armed);

/* Status flags that describe the drone now (STV_FLAG_ARMED when the motors may spin, STV_FLAG_INFLIGHT_TUNING). */
uint16_t stv_cmd_flags(const stv_cmd_t *c, int16_t thr, uint8_t armed);

/* The link's reported settings (status frame) made equal to the filter's. */
void stv_cmd_sync_link(const stv_filter_t *f, stv_link_t *link);

#ifdef __cplusplus
}
#endif

#endif /* STV_CMD_H */

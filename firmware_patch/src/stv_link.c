/* steval-link: telemetry link of one AHRS loop (see stv_link.h). */
#include "stv_link.h"

#include <string.h>

/* Aligned staging buffer for one frame (the fixed-size encoders store whole words). */
typedef union {
  uint32_t align;
  uint8_t b[STV_TEXT_FRAME_MAX + 3u];
} frame_buf_t;

/* A fixed-size frame: encoded straight into the TX queue when it fits in one piece there (no copy), else through
 * the staging buffer (a frame across the ring's wrap, or dropped and counted). */
#define STV_SEND_FIXED(q, encode, payload, size, keep)                      \
  do {                                                                      \
    uint8_t *dst_ = stv_txq_reserve((q), (size), (keep));                    \
    if (dst_) {                                                             \
      encode(dst_, (payload));                                              \
      stv_txq_commit((q), (size));                                          \
      return 1;                                                             \
    } else {                                                                \
      frame_buf_t f_;                                                       \
      encode(f_.b, (payload));                                              \
      return stv_txq_push_keep((q), f_.b, (size), (keep));                  \
    }                                                                       \
  } while (0)

int stv_send_attitude(stv_txq_t *q, const stv_attitude_t *att) {
  STV_SEND_FIXED(q, stv_encode_attitude, att, STV_ATTITUDE_FRAME_SIZE, STV_STATUS_FRAME_SIZE);
}

int stv_send_status(stv_txq_t *q, const stv_status_t *st) {
  STV_SEND_FIXED(q, stv_encode_status, st, STV_STATUS_FRAME_SIZE, 0u);
}

int stv_send_flight(stv_txq_t *q, const stv_flight_t *fc) {
  STV_SEND_FIXED(q, stv_encode_flight, fc, STV_FLIGHT_FRAME_SIZE, STV_STATUS_FRAME_SIZE);
}

int stv_send_ack(stv_txq_t *q, const stv_ack_t *ack) {
  STV_SEND_FIXED(q, stv_encode_ack, ack, STV_ACK_FRAME_SIZE, 0u);
}

uint32_t stv_send_text(stv_txq_t *q, const uint8_t *text, size_t len) {
  frame_buf_t f;
  uint32_t lost = 0;
  if (len == 0) {
    text = (const uint8_t *)" ";
    len = 1;
  }
  while (len) {
    size_t n = len > STV_TEXT_MAX_PAYLOAD ? STV_TEXT_MAX_PAYLOAD : len;
    size_t sz = stv_encode_frame(f.b, STV_TYPE_TEXT, text, n);
    if (!stv_txq_push_keep(q, f.b, (uint32_t)sz, STV_STATUS_FRAME_SIZE)) lost++;
    text += n;
    len -= n;
  }
  return lost;
}

static void reset_cycle_stats(stv_link_t *link) {
  link->cyc_min = UINT32_MAX;
  link->cyc_max = 0;
  link->cyc_n = 0;
  link->cyc_sum = 0;
}

void stv_link_init(stv_link_t *link, const stv_link_config_t *cfg, uint32_t cyc_now) {
  memset(link, 0, sizeof(*link));
  link->cfg = *cfg;
  if (link->cfg.text_decimation == 0) link->cfg.text_decimation = 1;
  if (link->cfg.status_every == 0) link->cfg.status_every = 1;
  if (link->cfg.text_mode) link->cfg.flags |= STV_FLAG_TEXT_MODE;
  link->cyc_per_us = cfg->cpu_hz / 1000000u;
  if (link->cyc_per_us == 0) link->cyc_per_us = 1;
  stv_txq_init(&link->txq);
  link->last_cyc = cyc_now;
  reset_cycle_stats(link);
}

void stv_link_update_time(stv_link_t *link, uint32_t cyc_now) {
  uint32_t delta = cyc_now - link->last_cyc; /* modulo 2^32: survives CYCCNT wrap-around */
  uint32_t us = delta / link->cyc_per_us;
  uint32_t rem = link->cyc_rem + (delta - us * link->cyc_per_us);
  link->last_cyc = cyc_now;
  if (rem >= link->cyc_per_us) {
    rem -= link->cyc_per_us;
    us++;
  }
  link->cyc_rem = rem;
  link->t_us += us; /* wraps at 2^32 as PROTOCOL.md says */
}

void stv_link_step_begin(stv_link_t *link, uint32_t cyc_now, int16_t thr) {
  stv_link_update_time(link, cyc_now);
  link->step_t_us = link->t_us;
  link->thr = thr;
  link->cyc_begin = cyc_now;
}

static float read_state(const volatile float *p) { return p ? *p : 0.0f; }

void stv_link_make_status(stv_link_t *link, stv_status_t *st) {
  const stv_link_config_t *c = &link->cfg;
  int i;
  memset(st, 0, sizeof(*st));
  st->step = link->step;
  st->t_us = link->step_t_us;
  for (i = 0; i < 4; i++) st->q[i] = read_state(c->q_state[i]);
  for (i = 0; i < 3; i++) st->int_xyz[i] = read_state(c->int_state[i]);
  st->kp_ground = c->kp_ground;
  st->kp_flight = c->kp_flight;
  st->ki = c->ki;
  st->dt_s = c->dt_s;
  if (link->cyc_n) {
    st->cyc_min = link->cyc_min;
    st->cyc_mean = (uint32_t)(link->cyc_sum / link->cyc_n);
    st->cyc_max = link->cyc_max;
  }
  st->cyc_n = (uint16_t)(link->cyc_n > 0xFFFFu ? 0xFFFFu : link->cyc_n);
  st->cpu_hz = c->cpu_hz;
  st->tx_dropped = link->txq.dropped;
  st->baud = c->baud;
  st->min_thr = c->min_thr;
  st->flags = c->flags;
  {
    uint32_t peak = stv_txq_take_peak(&link->txq);
    st->queue_peak = (uint16_t)(peak > 0xFFFFu ? 0xFFFFu : peak);
  }
  st->fw_version[0] = STV_FW_VERSION_MAJOR;
  st->fw_version[1] = STV_FW_VERSION_MINOR;
  st->fc_every = c->fc_every;
  st->param_gen = link->param_gen;
  reset_cycle_stats(link);
}

/* Text mode: one line, whole or dropped (counted). $STA lines use the reserve the others leave. */
static void push_line(stv_link_t *link, const char *s, size_t n, uint32_t keep_free) {
  (void)stv_txq_push_keep(&link->txq, (const uint8_t *)s, (uint32_t)n, keep_free);
}

void stv_link_step_end(stv_link_t *link, uint32_t cyc_now, const float acc_mg[3], const float gyro_mdps[3],
                       const float q[4], const float euler_rad[3]) {
  uint32_t cyc = cyc_now - link->cyc_begin;
  if (cyc < link->cyc_min) link->cyc_min = cyc;
  if (cyc > link->cyc_max) link->cyc_max = cyc;
  link->cyc_sum += cyc;
  link->cyc_n++;

  if (!link->cfg.text_mode) {
    stv_attitude_t att;
    att.t_us = link->step_t_us;
    memcpy(att.acc_mg, acc_mg, sizeof(att.acc_mg));
    memcpy(att.gyro_mdps, gyro_mdps, sizeof(att.gyro_mdps));
    memcpy(att.q, q, sizeof(att.q));
    att.thz_rad = euler_rad[2];
    att.seq = (uint16_t)link->step;
    att.thr = link->thr;
    stv_send_attitude(&link->txq, &att);
  } else if (link->step % link->cfg.text_decimation == 0u) {
    stv_att_line_t v;
    char line[STV_TEXT_LINE_MAX];
    v.step = link->step;
    v.t_us = link->step_t_us;
    v.thr = link->thr;
    v.thx_rad = euler_rad[0];
    v.thy_rad = euler_rad[1];
    v.thz_rad = euler_rad[2];
    memcpy(v.acc_mg, acc_mg, sizeof(v.acc_mg));
    memcpy(v.gyro_mdps, gyro_mdps, sizeof(v.gyro_mdps));
    push_line(link, line, stv_format_att_line(line, &v), STV_TEXT_LINE_MAX);
  }

  if (++link->since_status >= link->cfg.status_every) {
    stv_status_t st;
    link->since_status = 0;
    stv_link_make_status(link, &st);
    if (!link->cfg.text_mode) {
      stv_send_status(&link->txq, &st);
    } else {
      char line[STV_TEXT_LINE_MAX];
      push_line(link, line, stv_format_sta_line(line, &st), 0u);
    }
  }
  link->step++;
}

static void flush_line(stv_link_t *link) {
  if (link->line_len == 0) return;
  if (!link->cfg.text_mode) {
    stv_send_text(&link->txq, (const uint8_t *)link->line, link->line_len);
  } else {
    char buf[STV_TEXT_MAX_PAYLOAD + 3u];
    size_t n = link->line_len;
    memcpy(buf, link->line, n);
    if (buf[0] == '$') buf[0] = '#'; /* a log line must not look like a $ATT/$STA record */
    buf[n++] = '\r';
    buf[n++] = '\n';
    push_line(link, buf, n, STV_TEXT_LINE_MAX);
  }
  link->line_len = 0;
}

void stv_link_log_write(stv_link_t *link, const char *s, size_t n) {
  size_t i;
  for (i = 0; i < n; i++) {
    char c = s[i];
    if (c == '\n') {
      flush_line(link);
    } else if (c != '\r') {
      if (link->line_len == sizeof(link->line)) flush_line(link);
      link->line[link->line_len++] = c;
    }
  }
}

/* Frame requests -> frames (see stv_requests.h). */
#include "stv_requests.h"

#include <string.h>

static uint32_t rd_u32(const uint8_t *p) {
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static uint16_t rd_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static float rd_f32(const uint8_t *p) {
  uint32_t u = rd_u32(p);
  float f;
  memcpy(&f, &u, 4); /* the exact bits */
  return f;
}

static void parse_attitude(const uint8_t *p, stv_attitude_t *a) {
  int i;
  a->t_us = rd_u32(p);
  for (i = 0; i < 3; i++) a->acc_mg[i] = rd_f32(p + 4 + 4 * i);
  for (i = 0; i < 3; i++) a->gyro_mdps[i] = rd_f32(p + 16 + 4 * i);
  for (i = 0; i < 4; i++) a->q[i] = rd_f32(p + 28 + 4 * i);
  a->thz_rad = rd_f32(p + 44);
  a->seq = rd_u16(p + 48);
  a->thr = (int16_t)rd_u16(p + 50);
}

static void parse_status(const uint8_t *p, stv_status_t *s) {
  int i;
  s->step = rd_u32(p);
  s->t_us = rd_u32(p + 4);
  for (i = 0; i < 4; i++) s->q[i] = rd_f32(p + 8 + 4 * i);
  for (i = 0; i < 3; i++) s->int_xyz[i] = rd_f32(p + 24 + 4 * i);
  s->kp_ground = rd_f32(p + 36);
  s->kp_flight = rd_f32(p + 40);
  s->ki = rd_f32(p + 44);
  s->dt_s = rd_f32(p + 48);
  s->cyc_min = rd_u32(p + 52);
  s->cyc_mean = rd_u32(p + 56);
  s->cyc_max = rd_u32(p + 60);
  s->cpu_hz = rd_u32(p + 64);
  s->tx_dropped = rd_u32(p + 68);
  s->baud = rd_u32(p + 72);
  s->cyc_n = rd_u16(p + 76);
  s->min_thr = (int16_t)rd_u16(p + 78);
  s->flags = rd_u16(p + 80);
  s->queue_peak = rd_u16(p + 82);
  s->fw_version[0] = p[84];
  s->fw_version[1] = p[85];
  s->fw_version[2] = p[86];
  s->reserved = p[87];
}

static void drain(stv_txq_t *q, stv_sink_fn sink, void *ctx) {
  uint32_t len;
  const uint8_t *p;
  while ((p = stv_txq_peek(q, &len)), len) {
    sink(ctx, p, len);
    stv_txq_consume(q, len);
  }
}

int stv_run_requests(stv_txq_t *q, const uint8_t *in, size_t n, size_t *done, stv_sink_fn sink, void *ctx) {
  size_t pos = 0;
  int rc = STV_REQ_OK;
  while (pos < n) {
    uint8_t type, len;
    const uint8_t *payload;
    if (n - pos < 2u) {
      rc = STV_REQ_TRUNCATED;
      break;
    }
    type = in[pos];
    len = in[pos + 1];
    if (n - pos - 2u < len) {
      rc = STV_REQ_TRUNCATED;
      break;
    }
    payload = in + pos + 2;
    if (type == STV_TYPE_ATTITUDE) {
      stv_attitude_t a;
      if (len != STV_ATTITUDE_PAYLOAD_SIZE) {
        rc = STV_REQ_BAD_LENGTH;
        break;
      }
      parse_attitude(payload, &a);
      if (!stv_send_attitude(q, &a)) rc = STV_REQ_DROPPED;
    } else if (type == STV_TYPE_STATUS) {
      stv_status_t s;
      if (len != STV_STATUS_PAYLOAD_SIZE) {
        rc = STV_REQ_BAD_LENGTH;
        break;
      }
      parse_status(payload, &s);
      if (!stv_send_status(q, &s)) rc = STV_REQ_DROPPED;
    } else if (type == STV_TYPE_TEXT) {
      if (stv_send_text(q, payload, len)) rc = STV_REQ_DROPPED;
    } else {
      rc = STV_REQ_BAD_TYPE;
      break;
    }
    drain(q, sink, ctx);
    if (rc != STV_REQ_OK) break;
    pos += 2u + len;
  }
  *done = pos;
  return rc;
}

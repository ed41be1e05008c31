/* steval-link: host -> drone commands (see stv_cmd.h). */
#include "stv_cmd.h"

#include <string.h>

#define STV_VT_COMMAND ((uint8_t)((STV_VERSION << 4) | STV_TYPE_COMMAND))

void stv_rxq_init(stv_rxq_t *q) {
  q->head = 0;
  q->tail = 0;
  q->overruns = 0;
}

int stv_rxq_push(stv_rxq_t *q, uint8_t b) {
  uint32_t head = q->head;
  if (head - q->tail >= STV_RXQ_SIZE) {
    q->overruns++;
    return 0;
  }
  q->buf[head & (STV_RXQ_SIZE - 1u)] = b;
  q->head = head + 1u; /* published after the byte (single-core M4: stores are in program order) */
  return 1;
}

int stv_rxq_pop(stv_rxq_t *q, uint8_t *b) {
  uint32_t tail = q->tail;
  if (q->head == tail) return 0;
  *b = q->buf[tail & (STV_RXQ_SIZE - 1u)];
  q->tail = tail + 1u;
  return 1;
}

void stv_cmd_dec_init(stv_cmd_dec_t *d) { memset(d, 0, sizeof(*d)); }

/* Is buf[0..n-1] still the beginning of a command frame? Counts a candidate (a sync pair) that is not. */
static int prefix_ok(stv_cmd_dec_t *d) {
  const uint8_t *b = d->buf;
  uint32_t n = d->n;
  if (n >= 1u && b[0] != STV_SYNC0) return 0;
  if (n >= 2u && b[1] != STV_SYNC1) return 0;
  if ((n >= 3u && b[2] != STV_VT_COMMAND) || (n >= 4u && b[3] != STV_COMMAND_PAYLOAD_SIZE)) {
    d->rx_bad++;
    return 0;
  }
  return 1;
}

int stv_cmd_dec_feed(stv_cmd_dec_t *d, uint8_t byte, stv_command_t *cmd) {
  d->buf[d->n++] = byte;
  for (;;) {
    if (!prefix_ok(d)) {
      /* not a frame start: drop the first byte and look again at the rest (resync) */
      memmove(d->buf, d->buf + 1, --d->n);
      continue;
    }
    if (d->n < STV_COMMAND_FRAME_SIZE) return 0;
    {
      const uint32_t body = STV_HEADER_SIZE + STV_COMMAND_PAYLOAD_SIZE;
      uint32_t crc = stv_crc32_update(0u, d->buf + 2, body - 2u);
      uint32_t got = (uint32_t)d->buf[body] | (uint32_t)d->buf[body + 1u] << 8 |
                     (uint32_t)d->buf[body + 2u] << 16 | (uint32_t)d->buf[body + 3u] << 24;
      if (crc == got) {
        memcpy(cmd, d->buf + STV_HEADER_SIZE, sizeof(*cmd));
        d->n = 0;
        d->rx_ok++;
        return 1;
      }
      d->rx_bad++;
      memmove(d->buf, d->buf + 1, --d->n);
    }
  }
}

static int finite_f(float v) { return v == v && v - v == 0.0f; }

stv_cmd_outcome_t stv_cmd_handle(stv_filter_t *f, const stv_command_t *cmd, const stv_cmd_env_t *env) {
  stv_cmd_outcome_t o;
  o.result = STV_ACK_ACCEPTED;
  o.filter_changed = 0;
  o.reset_state = 0;
  o.send_status = 0;
  o.new_text_mode = -1;
  switch (cmd->cmd) {
  case STV_CMD_REQUEST_STATUS:
    o.send_status = 1;
    return o;
  case STV_CMD_SET_MODE:
    if (cmd->param > 1u) {
      o.result = STV_ACK_OUT_OF_RANGE;
      return o;
    }
    o.new_text_mode = (int8_t)cmd->param;
    o.send_status = 1;
    return o;
  case STV_CMD_RESET_FILTER:
  case STV_CMD_SET_PARAM:
    break;
  default:
    o.result = STV_ACK_UNKNOWN;
    return o;
  }
  if (cmd->cmd == STV_CMD_SET_PARAM) {
    float v = cmd->value;
    if (cmd->param < STV_PARAM_KP_GROUND || cmd->param > STV_PARAM_CORRECTION) {
      o.result = STV_ACK_UNKNOWN;
      return o;
    }
    if (!finite_f(v) || v < 0.0f) {
      o.result = STV_ACK_OUT_OF_RANGE;
      return o;
    }
    if (cmd->param <= STV_PARAM_KI && v > STV_GAIN_MAX) {
      o.result = STV_ACK_OUT_OF_RANGE;
      return o;
    }
    if (cmd->param == STV_PARAM_MIN_THR && (v > 32767.0f || v != (float)(int32_t)v)) {
      o.result = STV_ACK_OUT_OF_RANGE;
      return o;
    }
    if (cmd->param == STV_PARAM_CORRECTION && v != 0.0f && v != 1.0f) {
      o.result = STV_ACK_OUT_OF_RANGE;
      return o;
    }
  }
  if (!env->inflight_ok && stv_cmd_motors_may_spin(f, env)) {
    o.result = STV_ACK_REFUSED_ARMED;
    return o;
  }
  if (cmd->cmd == STV_CMD_RESET_FILTER) {
    o.reset_state = 1;
  } else {
    switch (cmd->param) {
    case STV_PARAM_KP_GROUND: f->kp_ground = cmd->value; break;
    case STV_PARAM_KP_FLIGHT: f->kp_flight = cmd->value; break;
    case STV_PARAM_KI: f->ki = cmd->value; break;
    case STV_PARAM_MIN_THR: f->min_thr = (int16_t)cmd->value; break;
    default: f->correction = (uint8_t)(cmd->value != 0.0f); break;
    }
  }
  o.filter_changed = 1;
  o.send_status = 1;
  return o;
}

int stv_cmd_next(stv_cmd_t *c, stv_command_t *cmd) {
  uint8_t b;
  while (stv_rxq_pop(&c->rx, &b))
    if (stv_cmd_dec_feed(&c->dec, b, cmd)) return 1;
  return 0;
}

uint16_t stv_cmd_flags(const stv_cmd_t *c, int16_t thr, uint8_t armed) {
  stv_cmd_env_t env;
  uint16_t flags = c->inflight_ok ? STV_FLAG_INFLIGHT_TUNING : 0u;
  env.thr = thr;
  env.armed = armed;
  if (stv_cmd_motors_may_spin(c->filter, &env)) flags |= STV_FLAG_ARMED;
  return flags;
}

void stv_cmd_sync_link(const stv_filter_t *f, stv_link_t *link) {
  stv_link_config_t *cfg = &link->cfg;
  cfg->kp_ground = f->kp_ground;
  cfg->kp_flight = f->kp_flight;
  cfg->ki = f->ki;
  cfg->min_thr = f->min_thr;
  if (f->correction)
    cfg->flags &= (uint16_t)~STV_FLAG_NO_CORRECTION;
  else
    cfg->flags |= STV_FLAG_NO_CORRECTION;
}

/* Text mode: "#ACK seq cmd result step rx_ok rx_bad" as a log line ('#': never taken for a $ record). */
static size_t format_ack_line(char *out, const stv_ack_t *a) {
  uint32_t v[6];
  size_t n = 0;
  int i;
  v[0] = a->cmd_seq;
  v[1] = a->cmd;
  v[2] = a->result;
  v[3] = a->step;
  v[4] = a->rx_ok;
  v[5] = a->rx_bad;
  memcpy(out, "#ACK", 4);
  n = 4;
  for (i = 0; i < 6; i++) {
    char digits[10];
    int k = 0;
    uint32_t x = v[i];
    do {
      digits[k++] = (char)('0' + x % 10u);
      x /= 10u;
    } while (x);
    out[n++] = ' ';
    while (k) out[n++] = digits[--k];
  }
  out[n++] = '\r';
  out[n++] = '\n';
  return n;
}

static void send_status_now(stv_cmd_t *c, stv_link_t *link, int16_t thr, uint8_t armed, uint16_t event) {
  stv_status_t st;
  stv_link_make_status(link, &st);
  st.step = link->step - 1u; /* the last step done: the settings and the snapshot apply from the next one */
  st.flags |= (uint16_t)(event | stv_cmd_flags(c, thr, armed));
  if (!link->cfg.text_mode) {
    stv_send_status(&link->txq, &st);
  } else {
    char line[STV_TEXT_LINE_MAX];
    (void)stv_txq_push(&link->txq, (const uint8_t *)line, (uint32_t)stv_format_sta_line(line, &st));
  }
}

void stv_cmd_execute(stv_cmd_t *c, stv_link_t *link, const stv_command_t *cmd, int16_t thr, uint8_t armed) {
  stv_cmd_env_t env;
  stv_cmd_outcome_t o;
  stv_ack_t ack;
  env.thr = thr;
  env.armed = armed;
  env.inflight_ok = c->inflight_ok;
  env.text_mode = link->cfg.text_mode;
  o = stv_cmd_handle(c->filter, cmd, &env);
  /* The first change since boot: a status with the build's settings goes first (not EVENT: nothing changed yet),
   * so that a capture from power-up states them even when no periodic status came before the change. */
  if (o.filter_changed && link->param_gen == 0u) send_status_now(c, link, thr, armed, 0u);
  if (o.reset_state) {
    int i;
    for (i = 0; i < 4; i++)
      if (c->q[i]) *c->q[i] = i == 0 ? 1.0f : 0.0f;
    for (i = 0; i < 3; i++)
      if (c->ints[i]) *c->ints[i] = 0.0f;
  }
  if (o.filter_changed) {
    stv_cmd_sync_link(c->filter, link);
    link->param_gen++;
  }
  memset(&ack, 0, sizeof(ack));
  ack.cmd_seq = cmd->cmd_seq;
  ack.cmd = cmd->cmd;
  ack.result = o.result;
  ack.step = link->step; /* the next step: the first one an accepted change applies to */
  ack.rx_ok = (uint16_t)c->dec.rx_ok;
  ack.rx_bad = (uint16_t)c->dec.rx_bad;
  /* the ack goes out in the mode in force when the command arrived (SET_MODE switches after it) */
  if (!link->cfg.text_mode) {
    stv_send_ack(&link->txq, &ack);
  } else {
    char line[48];
    (void)stv_txq_push(&link->txq, (const uint8_t *)line, (uint32_t)format_ack_line(line, &ack));
  }
  if (o.new_text_mode >= 0) {
    link->cfg.text_mode = (uint8_t)o.new_text_mode;
    if (o.new_text_mode)
      link->cfg.flags |= STV_FLAG_TEXT_MODE;
    else
      link->cfg.flags &= (uint16_t)~STV_FLAG_TEXT_MODE;
  }
  if (o.send_status) send_status_now(c, link, thr, armed, STV_FLAG_EVENT);
}

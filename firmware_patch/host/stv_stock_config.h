/* The link configuration of ST's stock firmware (kp 10 below MIN_THR 200, 0.4 above; ki 0.1; dt 6.25 ms; 84 MHz;
 * 115200 baud; a text line every 16 steps, a status frame every 162), for the host tests and the emulator harness.
 * The state pointers (q_state, int_state) are left NULL for the caller to set. */
#ifndef STV_STOCK_CONFIG_H
#define STV_STOCK_CONFIG_H

#include <string.h>

#include "stv_link.h"

static inline stv_link_config_t stv_stock_config(void) {
  stv_link_config_t c;
  memset(&c, 0, sizeof(c));
  c.kp_ground = 10.0f;
  c.kp_flight = 0.4f;
  c.ki = 0.1f;
  c.dt_s = 0.00625f;
  c.min_thr = 200;
  c.cpu_hz = 84000000u;
  c.baud = 115200u;
  c.text_decimation = 16u;
  c.status_every = 162u;
  return c;
}

#endif

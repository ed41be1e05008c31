/* Host tests of the firmware patch's C core (gcc). Run by tests/test_firmware_host.py.
 *
 *   test_stv selftest    C-level checks (CRC, queue overflow/wrap, time accumulation, log lines); prints "ok N"
 *   test_stv link        drive stv_link like the firmware main loop from commands on stdin, frames on stdout
 *
 * `link` commands (little-endian):
 *   'C' u8 text_mode, u32 text_decimation, u32 status_every, u32 cpu_hz, u32 baud, f32 ki, u16 flags,
 *       u32 cyc0, u32 t_us0, u32 step0             (re)initialise the link; t_us/step start at t_us0/step0
 *   'S' u32 cyc_begin, u32 cyc_end, i16 thr, f32 acc[3], gyro[3], q[4], euler[3], state_q[4], state_int[3]
 *       one AHRS step (state_* are the ahrs.c globals after the step, read by the status snapshot)
 *   'L' u16 n, bytes[n]                            log output (as PRINTF would write it)
 *   'D' u32 n                                      the UART sends up to n queued bytes (to stdout)
 * At the end everything still queued is written. Stderr gets "dropped=<n> peak=<bytes>".
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "stv_check.h"
#include "stv_link.h"
#include "stv_stock_config.h"

static uint32_t crc_bitwise(const uint8_t *d, size_t n) {
  uint32_t crc = 0xFFFFFFFFu;
  size_t i;
  int b;
  for (i = 0; i < n; i++) {
    crc ^= d[i];
    for (b = 0; b < 8; b++) crc = (crc & 1u) ? (crc >> 1) ^ 0xEDB88320u : crc >> 1;
  }
  return ~crc;
}

static uint32_t lcg_state = 12345u;
static uint32_t lcg(void) {
  lcg_state = lcg_state * 1664525u + 1013904223u;
  return lcg_state;
}

static void test_crc(void) {
  uint8_t buf[300];
  size_t n, i;
  CHECK(stv_crc32_update(0u, (const uint8_t *)"123456789", 9) == 0xCBF43926u);
  for (n = 0; n < sizeof(buf); n++) {
    for (i = 0; i < n; i++) buf[i] = (uint8_t)(lcg() >> 24);
    CHECK(stv_crc32_update(0u, buf, n) == crc_bitwise(buf, n));
    if (n > 3) CHECK(stv_crc32_update(0u, buf + 1, n - 1) == crc_bitwise(buf + 1, n - 1)); /* unaligned */
    if (n > 7) CHECK(stv_crc32_update(stv_crc32_update(0u, buf, 5), buf + 5, n - 5) == crc_bitwise(buf, n));
  }
}

static void test_fixed_vs_generic(void) {
  union { uint32_t a; uint8_t b[300]; } f1, f2;
  stv_attitude_t att;
  stv_status_t st;
  size_t i, n;
  for (i = 0; i < sizeof(att); i++) ((uint8_t *)&att)[i] = (uint8_t)(lcg() >> 24);
  for (i = 0; i < sizeof(st); i++) ((uint8_t *)&st)[i] = (uint8_t)(lcg() >> 24);
  n = stv_encode_attitude(f1.b, &att);
  CHECK(n == 60);
  CHECK(stv_encode_frame(f2.b, STV_TYPE_ATTITUDE, (const uint8_t *)&att, sizeof(att)) == 60);
  CHECK(memcmp(f1.b, f2.b, 60) == 0);
  CHECK(f1.b[0] == 0xA5 && f1.b[1] == 0x5A && f1.b[2] == 0x21 && f1.b[3] == 52);
  CHECK(crc_bitwise(f1.b + 2, 54) == ((uint32_t)f1.b[56] | ((uint32_t)f1.b[57] << 8) | ((uint32_t)f1.b[58] << 16) |
                                     ((uint32_t)f1.b[59] << 24)));
  n = stv_encode_status(f1.b, &st);
  CHECK(n == 96);
  CHECK(stv_encode_frame(f2.b, STV_TYPE_STATUS, (const uint8_t *)&st, sizeof(st)) == 96);
  CHECK(memcmp(f1.b, f2.b, 96) == 0);
  CHECK(f1.b[2] == 0x22 && f1.b[3] == 88);
  {
    stv_flight_t fc;
    stv_ack_t ack;
    stv_command_t cmd;
    for (i = 0; i < sizeof(fc); i++) ((uint8_t *)&fc)[i] = (uint8_t)(lcg() >> 24);
    for (i = 0; i < sizeof(ack); i++) ((uint8_t *)&ack)[i] = (uint8_t)(lcg() >> 24);
    for (i = 0; i < sizeof(cmd); i++) ((uint8_t *)&cmd)[i] = (uint8_t)(lcg() >> 24);
    CHECK(stv_encode_flight(f1.b, &fc) == 80);
    CHECK(stv_encode_frame(f2.b, STV_TYPE_FLIGHT, (const uint8_t *)&fc, sizeof(fc)) == 80);
    CHECK(memcmp(f1.b, f2.b, 80) == 0 && f1.b[2] == 0x24 && f1.b[3] == 72);
    CHECK(stv_encode_ack(f1.b, &ack) == 20);
    CHECK(stv_encode_frame(f2.b, STV_TYPE_ACK, (const uint8_t *)&ack, sizeof(ack)) == 20);
    CHECK(memcmp(f1.b, f2.b, 20) == 0 && f1.b[2] == 0x25 && f1.b[3] == 12);
    CHECK(stv_encode_command(f1.b, &cmd) == 20);
    CHECK(stv_encode_frame(f2.b, STV_TYPE_COMMAND, (const uint8_t *)&cmd, sizeof(cmd)) == 20);
    CHECK(memcmp(f1.b, f2.b, 20) == 0 && f1.b[2] == 0x28 && f1.b[3] == 12);
  }
}

static void test_queue(void) {
  static stv_txq_t q;
  uint8_t frame[58], out[STV_TXQ_SIZE];
  uint32_t i, fit = STV_TXQ_SIZE / 58u, n;
  stv_txq_init(&q);
  for (i = 0; i < sizeof(frame); i++) frame[i] = (uint8_t)i;
  for (i = 0; i < fit; i++) CHECK(stv_txq_push(&q, frame, 58) == 1);
  for (i = 0; i < 10; i++) CHECK(stv_txq_push(&q, frame, 58) == 0); /* full: dropped, never blocks */
  CHECK(q.dropped == 10);
  CHECK(stv_txq_used(&q) == fit * 58u);
  CHECK(stv_txq_take_peak(&q) == fit * 58u);
  /* a frame that almost fits is still refused whole */
  n = stv_txq_pop(&q, out, 57);
  CHECK(n == 57);
  {
    int fits = STV_TXQ_SIZE - stv_txq_used(&q) >= 58u;
    CHECK(stv_txq_push(&q, frame, 58) == fits);
    CHECK(q.dropped == 10u + (fits ? 0u : 1u));
  }
  /* free-running indices across 2^32, ring wrap in the middle of a frame */
  stv_txq_init(&q);
  q.head = q.tail = 0xFFFFFFFFu - 100u;
  for (i = 0; i < 1000; i++) {
    uint8_t b[58];
    uint32_t k;
    for (k = 0; k < 58; k++) frame[k] = (uint8_t)(i * 7u + k);
    CHECK(stv_txq_push(&q, frame, 58) == 1);
    CHECK(stv_txq_pop(&q, b, 58) == 58);
    CHECK(memcmp(b, frame, 58) == 0);
  }
  CHECK(q.dropped == 0);
  CHECK(q.head == q.tail);
  CHECK(q.head < 0x10000u); /* has wrapped */
}

static void test_time(void) {
  static stv_link_t link;
  stv_link_config_t c = stv_stock_config();
  uint32_t cyc = 0xFFFFFFFFu - 5000000u, i;
  uint64_t total = 0;
  stv_link_init(&link, &c, cyc);
  for (i = 0; i < 20000; i++) { /* 2 minutes of 6.19 ms steps with jitter: CYCCNT wraps twice */
    uint32_t d = 519960u + (lcg() >> 20);
    cyc += d;
    total += d;
    stv_link_update_time(&link, cyc);
    CHECK(link.t_us == (uint32_t)(total / 84u));
  }
  /* t_us wraps at 2^32 */
  link.t_us = 0xFFFFFFFFu - 10u;
  stv_link_update_time(&link, cyc + 84u * 20u);
  CHECK(link.t_us == 9u);
}

static void test_log_lines(void) {
  static stv_link_t link;
  stv_link_config_t c = stv_stock_config();
  char longline[600];
  uint8_t out[4096];
  uint32_t n;
  memset(longline, 'x', sizeof(longline));
  stv_link_init(&link, &c, 0);
  stv_link_log_write(&link, "Hello\r\n\n", 8);
  stv_link_log_write(&link, "par", 3);
  stv_link_log_write(&link, "tial\n", 5);
  stv_link_log_write(&link, longline, sizeof(longline));
  stv_link_log_write(&link, "\n", 1);
  n = stv_txq_pop(&link.txq, out, sizeof(out));
  /* "Hello" (5), "partial" (7), 600 x -> 255 + 255 + 90: 5 frames */
  CHECK(n == (4 + 5 + 4) + (4 + 7 + 4) + 2 * (4 + 255 + 4) + (4 + 90 + 4));
  CHECK(memcmp(out + 4, "Hello", 5) == 0 && out[3] == 5 && out[2] == 0x23);
  CHECK(memcmp(out + 17, "partial", 7) == 0);
}

static int selftest(void) {
  test_crc();
  test_fixed_vs_generic();
  test_queue();
  test_time();
  test_log_lines();
  if (checks_failed()) return 1;
  printf("ok %d\n", checks);
  return 0;
}

/* ---- link driver ---------------------------------------------------------------------------------------- */

static int rd(void *dst, size_t n) { return fread(dst, 1, n, stdin) == n; }

static void drain(stv_txq_t *q, uint32_t max) {
  while (max) {
    uint32_t len;
    const uint8_t *p = stv_txq_peek(q, &len);
    if (!len) break;
    if (len > max) len = max;
    fwrite(p, 1, len, stdout);
    stv_txq_consume(q, len);
    max -= len;
  }
}

static int link_driver(void) {
  static stv_link_t link;
  static float state_q[4], state_int[3];
  int op, have = 0, i;
  uint32_t max_peak = 0;
  while ((op = getchar()) != EOF) {
    if (op == 'C') {
      stv_link_config_t c = stv_stock_config();
      uint8_t tm;
      uint32_t cyc0, t0, step0;
      if (!(rd(&tm, 1) && rd(&c.text_decimation, 4) && rd(&c.status_every, 4) && rd(&c.cpu_hz, 4) &&
            rd(&c.baud, 4) && rd(&c.ki, 4) && rd(&c.flags, 2) && rd(&cyc0, 4) && rd(&t0, 4) && rd(&step0, 4)))
        return 3;
      c.text_mode = tm;
      for (i = 0; i < 4; i++) c.q_state[i] = &state_q[i];
      for (i = 0; i < 3; i++) c.int_state[i] = &state_int[i];
      stv_link_init(&link, &c, cyc0);
      link.t_us = t0;
      link.step = step0;
      have = 1;
    } else if (op == 'S') {
      uint32_t c0, c1;
      int16_t thr;
      float acc[3], gyro[3], q[4], eul[3];
      if (!have) return 4;
      if (!(rd(&c0, 4) && rd(&c1, 4) && rd(&thr, 2) && rd(acc, 12) && rd(gyro, 12) && rd(q, 16) && rd(eul, 12) &&
            rd(state_q, 16) && rd(state_int, 12)))
        return 3;
      stv_link_step_begin(&link, c0, thr);
      stv_link_step_end(&link, c1, acc, gyro, q, eul);
      if (stv_txq_used(&link.txq) > max_peak) max_peak = stv_txq_used(&link.txq);
    } else if (op == 'L') {
      uint16_t n;
      char buf[65536];
      if (!have) return 4;
      if (!(rd(&n, 2) && rd(buf, n))) return 3;
      stv_link_log_write(&link, buf, n);
    } else if (op == 'D') {
      uint32_t n;
      if (!have) return 4;
      if (!rd(&n, 4)) return 3;
      drain(&link.txq, n);
    } else {
      fprintf(stderr, "unknown command 0x%02X\n", op);
      return 2;
    }
  }
  if (have) {
    drain(&link.txq, 0xFFFFFFFFu);
    fprintf(stderr, "dropped=%u peak=%u\n", (unsigned)link.txq.dropped, (unsigned)max_peak);
  }
  return 0;
}

int main(int argc, char **argv) {
  if (argc == 2 && !strcmp(argv[1], "selftest")) return selftest();
  if (argc == 2 && !strcmp(argv[1], "link")) return link_driver();
  fprintf(stderr, "usage: %s selftest | link < commands > frames\n", argv[0]);
  return 2;
}

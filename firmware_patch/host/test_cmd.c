/* Host tests of the command receiver (src/stv_cmd.c). Run by tests/test_firmware_cmd.py.
 *
 *   test_cmd selftest   decoder fuzz (random bytes, corrupted, partial and spliced valid commands: exactly the
 *                       intact commands come out, nothing else), command checks and safety, the link glue
 *                       (ack, EVENT status, reset, mode switch); prints "ok N"
 *   test_cmd decode     bytes on stdin -> the 12-byte payload of every accepted command frame on stdout;
 *                       stderr gets "rx_ok=<n> rx_bad=<n>"
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "stv_check.h"
#include "stv_cmd.h"
#include "stv_stock_config.h"

static uint64_t rng_state = 0x9E3779B97F4A7C15ull;
static uint32_t rnd(void) { /* xorshift64* */
  rng_state ^= rng_state >> 12;
  rng_state ^= rng_state << 25;
  rng_state ^= rng_state >> 27;
  return (uint32_t)((rng_state * 2685821657736338717ull) >> 32);
}
static uint32_t rnd_below(uint32_t n) { return rnd() % n; }

typedef union {
  uint32_t align;
  uint8_t b[STV_COMMAND_FRAME_SIZE];
} cmd_frame_t;

static stv_command_t random_command(uint16_t seq) {
  stv_command_t c;
  uint32_t bits = rnd();
  c.cmd_seq = seq;
  c.cmd = (uint8_t)(1u + rnd_below(5));
  c.param = (uint8_t)rnd_below(7);
  memcpy(&c.value, &bits, 4);
  c.reserved = rnd_below(4) ? 0u : rnd();
  return c;
}

/* ---- decoder fuzz ---------------------------------------------------------------------------------------- */

#define MAX_STREAM (1u << 22)
static uint32_t fuzz_extra, fuzz_lost, fuzz_intact;
#define MAX_SENT 60000u

static uint8_t stream[MAX_STREAM];
static stv_command_t sent[MAX_SENT];   /* the intact frames, in stream order */
static stv_command_t by_seq[65536];    /* every command encoded this round (whole, damaged or cut), by cmd_seq */
static uint8_t known[65536];
static int32_t intact_index[65536];    /* index in sent[] of an intact frame, by cmd_seq; -1 otherwise */

static size_t put(size_t n, const uint8_t *src, size_t len) {
  if (n + len > MAX_STREAM) return n;
  memcpy(stream + n, src, len);
  return n + len;
}

/* One stream of noise, intact, corrupted, cut and spliced command frames. The decoder must return nothing but
 * commands the host encoded, and the intact ones in order. A frame cut short may still come out when the byte
 * after the cut happens to be its missing last byte (20 bytes of a frame the host did send); when that byte was
 * the sync byte of an intact frame, that one is lost. Both are counted and must stay rare (1/256 of the frames cut
 * just before their last byte). */
static void fuzz_round(uint32_t segments) {
  size_t n = 0;
  uint32_t n_sent = 0, n_got = 0, i, matched = 0, forged = 0, disorder = 0;
  int32_t last_index = -1;
  uint16_t seq = (uint16_t)rnd();
  memset(known, 0, sizeof(known));
  memset(intact_index, 0xFF, sizeof(intact_index));
  stv_cmd_dec_t d;
  stv_command_t got;
  for (i = 0; i < segments && n + 64 < MAX_STREAM && n_sent < MAX_SENT; i++) {
    cmd_frame_t f, g;
    stv_command_t c = random_command(seq++);
    uint32_t kind = rnd_below(8), k;
    by_seq[c.cmd_seq] = c;
    known[c.cmd_seq] = 1;
    stv_encode_command(f.b, &c);
    switch (kind) {
    case 0: { /* noise, sometimes with sync pairs and command headers in it */
      uint8_t noise[48];
      uint32_t len = rnd_below(sizeof(noise));
      for (k = 0; k < len; k++) noise[k] = (uint8_t)rnd();
      if (len >= 4 && rnd_below(2)) memcpy(noise + rnd_below(len - 3), f.b, 4);
      n = put(n, noise, len);
      break;
    }
    case 1: case 2: /* intact */
      n = put(n, f.b, sizeof(f.b));
      intact_index[c.cmd_seq] = (int32_t)n_sent;
      sent[n_sent++] = c;
      break;
    case 3: { /* 1..4 distinct bits flipped anywhere */
      uint32_t flips = 1u + rnd_below(4), first = rnd_below(8u * sizeof(f.b));
      for (k = 0; k < flips; k++) {
        uint32_t bit = (first + k * 37u) % (8u * sizeof(f.b));
        f.b[bit / 8u] ^= (uint8_t)(1u << (bit % 8u));
      }
      n = put(n, f.b, sizeof(f.b));
      break;
    }
    case 4: /* cut short */
      n = put(n, f.b, 1u + rnd_below(sizeof(f.b) - 1u));
      break;
    case 5: { /* spliced: the start of this one, the end of another */
      stv_command_t c2 = random_command((uint16_t)(seq + 30000u)); /* cmd_seq never one of this round's own */
      uint32_t cut = 1u + rnd_below(sizeof(f.b) - 1u);
      uint8_t h[STV_COMMAND_FRAME_SIZE];
      by_seq[c2.cmd_seq] = c2;
      known[c2.cmd_seq] = 1;
      stv_encode_command(g.b, &c2);
      memcpy(h, f.b, cut);
      memcpy(h + cut, g.b + cut, sizeof(h) - cut);
      n = put(n, h, sizeof(h));
      /* a cut inside the common header gives the other frame whole; a tail that agrees, this one */
      if (memcmp(h, f.b, sizeof(h)) == 0) {
        intact_index[c.cmd_seq] = (int32_t)n_sent;
        sent[n_sent++] = c;
      } else if (memcmp(h, g.b, sizeof(h)) == 0) {
        intact_index[c2.cmd_seq] = (int32_t)n_sent;
        sent[n_sent++] = c2;
      }
      break;
    }
    case 6: { /* a valid frame of another type or version */
      uint8_t other[40];
      size_t len = stv_encode_frame(other, (uint8_t)(1u + rnd_below(5)), f.b + 4, 12);
      if (rnd_below(2)) other[2] = (uint8_t)((1u << 4) | STV_TYPE_COMMAND); /* a v1 "command" */
      n = put(n, other, len);
      break;
    }
    default: { /* a byte dropped (UART overrun) */
      uint32_t drop = rnd_below(sizeof(f.b));
      n = put(n, f.b, drop);
      n = put(n, f.b + drop + 1u, sizeof(f.b) - drop - 1u);
      break;
    }
    }
  }
  stv_cmd_dec_init(&d);
  for (i = 0; i < n; i++) {
    if (stv_cmd_dec_feed(&d, stream[i], &got)) {
      n_got++;
      if (!known[got.cmd_seq] || memcmp(&got, &by_seq[got.cmd_seq], sizeof(got)) != 0) forged++;
      if (intact_index[got.cmd_seq] >= 0 && memcmp(&got, &sent[intact_index[got.cmd_seq]], sizeof(got)) == 0) {
        if (intact_index[got.cmd_seq] <= last_index) disorder++;
        last_index = intact_index[got.cmd_seq];
        matched++;
      }
    }
  }
  CHECK(forged == 0);   /* nothing the host did not send */
  CHECK(disorder == 0); /* in order, each once */
  CHECK(n_sent - matched <= n_got - matched); /* an intact frame is only lost to a chance completion before it */
  CHECK(n_got - matched <= n_sent / 500u + 2u); /* chance completions: rare */
  CHECK(d.rx_ok == n_got);
  CHECK(d.rx_bad > n_sent);
  fuzz_extra += n_got - matched;
  fuzz_lost += n_sent - matched;
  fuzz_intact += n_sent;
}

static void fuzz_random_bytes(void) {
  /* 4 MB of random bytes, then random bytes with a command header every few bytes (each a CRC check) */
  stv_cmd_dec_t d;
  stv_command_t got;
  uint32_t i, applied = 0;
  static const uint8_t head[4] = {STV_SYNC0, STV_SYNC1, (STV_VERSION << 4) | STV_TYPE_COMMAND, 12};
  stv_cmd_dec_init(&d);
  for (i = 0; i < (4u << 20); i++) applied += (uint32_t)stv_cmd_dec_feed(&d, (uint8_t)rnd(), &got);
  CHECK(applied == 0);
  stv_cmd_dec_init(&d);
  for (i = 0; i < 400000u; i++) {
    uint32_t k, len = rnd_below(24);
    for (k = 0; k < 4; k++) applied += (uint32_t)stv_cmd_dec_feed(&d, head[k], &got);
    for (k = 0; k < len; k++) applied += (uint32_t)stv_cmd_dec_feed(&d, (uint8_t)rnd(), &got);
  }
  CHECK(applied == 0);
  CHECK(d.rx_ok == 0);
  CHECK(d.rx_bad >= 350000u);
}

static void test_decoder_basics(void) {
  stv_cmd_dec_t d;
  stv_command_t c = random_command(7), got;
  cmd_frame_t f;
  uint32_t i, hits = 0;
  stv_encode_command(f.b, &c);
  stv_cmd_dec_init(&d);
  /* a frame cut after its header, then the whole frame: found (resync inside the buffered bytes) */
  for (i = 0; i < 9; i++) hits += (uint32_t)stv_cmd_dec_feed(&d, f.b[i], &got);
  for (i = 0; i < sizeof(f.b); i++) hits += (uint32_t)stv_cmd_dec_feed(&d, f.b[i], &got);
  CHECK(hits == 1);
  CHECK(memcmp(&got, &c, sizeof(c)) == 0);
  CHECK(d.rx_ok == 1 && d.rx_bad == 1);
  /* a decoder never holds more than one frame of bytes */
  CHECK(d.n == 0);
}

/* ---- command checks --------------------------------------------------------------------------------------- */

static stv_filter_t stock_filter(void) {
  stv_filter_t f = {10.0f, 0.4f, 0.1f, 200, 1};
  return f;
}

static stv_command_t cmd_of(uint8_t cmd, uint8_t param, float value) {
  stv_command_t c;
  memset(&c, 0, sizeof(c));
  c.cmd_seq = 1;
  c.cmd = cmd;
  c.param = param;
  c.value = value;
  return c;
}

static void test_handle(void) {
  stv_filter_t f = stock_filter(), before;
  stv_cmd_env_t idle = {0, 0, 0, 0}, thr_up = {200, 0, 0, 0}, armed = {0, 1, 0, 0}, tuning = {500, 1, 1, 0};
  stv_command_t c;
  stv_cmd_outcome_t o;
  float inf = 1e30f * 1e30f;

  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KI, 1.0f);
  o = stv_cmd_handle(&f, &c, &idle);
  CHECK(o.result == STV_ACK_ACCEPTED && o.filter_changed && o.send_status && f.ki == 1.0f);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_CORRECTION, 0.0f);
  o = stv_cmd_handle(&f, &c, &idle);
  CHECK(o.result == STV_ACK_ACCEPTED && f.correction == 0);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_MIN_THR, 300.0f);
  o = stv_cmd_handle(&f, &c, &idle);
  CHECK(o.result == STV_ACK_ACCEPTED && f.min_thr == 300);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KP_GROUND, 2.5f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_ACCEPTED && f.kp_ground == 2.5f);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KP_FLIGHT, 0.25f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_ACCEPTED && f.kp_flight == 0.25f);

  /* refused while the motors may spin: throttle at MIN_THR (now 300) or above, or armed; nothing changes */
  f = stock_filter();
  before = f;
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KI, 1.0f);
  o = stv_cmd_handle(&f, &c, &thr_up);
  CHECK(o.result == STV_ACK_REFUSED_ARMED && !o.filter_changed && !o.send_status);
  o = stv_cmd_handle(&f, &c, &armed);
  CHECK(o.result == STV_ACK_REFUSED_ARMED);
  c = cmd_of(STV_CMD_RESET_FILTER, 0, 0.0f);
  o = stv_cmd_handle(&f, &c, &armed);
  CHECK(o.result == STV_ACK_REFUSED_ARMED && !o.reset_state);
  CHECK(memcmp(&f, &before, sizeof(f)) == 0);
  thr_up.thr = 199;
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KI, 1.0f);
  CHECK(stv_cmd_handle(&f, &c, &thr_up).result == STV_ACK_ACCEPTED);
  /* ... unless the build allows in-flight tuning */
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KI, 0.5f);
  CHECK(stv_cmd_handle(&f, &c, &tuning).result == STV_ACK_ACCEPTED && f.ki == 0.5f);
  /* status requests and mode switches are always fine */
  c = cmd_of(STV_CMD_REQUEST_STATUS, 0, 0.0f);
  o = stv_cmd_handle(&f, &c, &armed);
  CHECK(o.result == STV_ACK_ACCEPTED && o.send_status && !o.filter_changed);
  c = cmd_of(STV_CMD_SET_MODE, 1, 0.0f);
  o = stv_cmd_handle(&f, &c, &armed);
  CHECK(o.result == STV_ACK_ACCEPTED && o.new_text_mode == 1);

  /* ranges and unknowns, nothing applied */
  f = stock_filter();
  before = f;
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KI, -1.0f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_OUT_OF_RANGE);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KI, inf);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_OUT_OF_RANGE);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KI, inf - inf);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_OUT_OF_RANGE);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KP_GROUND, 5000.0f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_OUT_OF_RANGE);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_MIN_THR, 200.5f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_OUT_OF_RANGE);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_MIN_THR, 40000.0f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_OUT_OF_RANGE);
  c = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_CORRECTION, 2.0f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_OUT_OF_RANGE);
  c = cmd_of(STV_CMD_SET_PARAM, 9, 1.0f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_UNKNOWN);
  c = cmd_of(STV_CMD_SET_PARAM, 0, 1.0f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_UNKNOWN);
  c = cmd_of(99, 0, 0.0f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_UNKNOWN);
  c = cmd_of(STV_CMD_SET_MODE, 2, 0.0f);
  CHECK(stv_cmd_handle(&f, &c, &idle).result == STV_ACK_OUT_OF_RANGE);
  CHECK(memcmp(&f, &before, sizeof(f)) == 0);
}

/* ---- the link glue ---------------------------------------------------------------------------------------- */

static size_t drain_all(stv_txq_t *q, uint8_t *out, size_t max) {
  size_t n = 0;
  uint8_t b;
  while (n < max && stv_txq_pop_byte(q, &b)) out[n++] = b;
  return n;
}

static void test_execute(void) {
  stv_link_t link;
  stv_link_config_t cfg = stv_stock_config();
  stv_cmd_t c;
  stv_filter_t f = stock_filter();
  float q[4] = {0.5f, 0.5f, 0.5f, 0.5f}, ints[3] = {1, 2, 3};
  float z[4] = {0};
  uint8_t out[512];
  size_t n;
  cmd_frame_t fr;
  stv_command_t cmd = cmd_of(STV_CMD_RESET_FILTER, 0, 0.0f), got;
  int i;
  stv_status_t st;
  stv_ack_t ack;

  cfg.status_every = 1000u;
  cfg.text_decimation = 1u;
  for (i = 0; i < 4; i++) cfg.q_state[i] = &q[i];
  for (i = 0; i < 3; i++) cfg.int_state[i] = &ints[i];
  stv_link_init(&link, &cfg, 0);
  memset(&c, 0, sizeof(c));
  stv_rxq_init(&c.rx);
  stv_cmd_dec_init(&c.dec);
  c.filter = &f;
  for (i = 0; i < 4; i++) c.q[i] = &q[i];
  for (i = 0; i < 3; i++) c.ints[i] = &ints[i];
  for (i = 0; i < 5; i++) stv_link_step_end(&link, 100u, z, z, z, z); /* steps 0..4 done */
  (void)drain_all(&link.txq, out, sizeof(out));

  /* nothing received: nothing to do */
  CHECK(!stv_cmd_next(&c, &got));
  cmd.cmd_seq = 41;
  stv_encode_command(fr.b, &cmd);
  for (i = 0; i < 20; i++) CHECK(stv_rxq_push(&c.rx, fr.b[i]));
  CHECK(stv_cmd_next(&c, &got));
  stv_cmd_execute(&c, &link, &got, 0, 0);
  CHECK(q[0] == 1.0f && q[1] == 0.0f && q[2] == 0.0f && q[3] == 0.0f);
  CHECK(ints[0] == 0.0f && ints[1] == 0.0f && ints[2] == 0.0f);
  CHECK(link.param_gen == 1);
  n = drain_all(&link.txq, out, sizeof(out));
  /* the first change since boot: a status with the build's settings and state first (not EVENT), the ack, then
   * the EVENT status with the new state */
  CHECK(n == STV_STATUS_FRAME_SIZE + STV_ACK_FRAME_SIZE + STV_STATUS_FRAME_SIZE);
  memcpy(&st, out + 4, sizeof(st));
  CHECK((out[2] & 0x0F) == STV_TYPE_STATUS && st.step == 4 && !(st.flags & STV_FLAG_EVENT) && st.param_gen == 0);
  CHECK(st.q[0] == 0.5f && st.int_xyz[2] == 3.0f);
  memcpy(&ack, out + STV_STATUS_FRAME_SIZE + 4, sizeof(ack));
  CHECK(out[STV_STATUS_FRAME_SIZE + 3] == STV_ACK_PAYLOAD_SIZE && (out[STV_STATUS_FRAME_SIZE + 2] & 0x0F) == STV_TYPE_ACK);
  CHECK(ack.cmd_seq == 41 && ack.cmd == STV_CMD_RESET_FILTER && ack.result == STV_ACK_ACCEPTED);
  CHECK(ack.step == 5 && ack.rx_ok == 1 && ack.rx_bad == 0);
  memcpy(&st, out + STV_STATUS_FRAME_SIZE + STV_ACK_FRAME_SIZE + 4, sizeof(st));
  CHECK((out[STV_STATUS_FRAME_SIZE + STV_ACK_FRAME_SIZE + 2] & 0x0F) == STV_TYPE_STATUS);
  CHECK(st.step == 4 && (st.flags & STV_FLAG_EVENT) && st.param_gen == 1 && st.q[0] == 1.0f && st.int_xyz[2] == 0.0f);

  /* KI while armed: refused, the ack says why, no status, nothing changed */
  cmd = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_KI, 1.0f);
  cmd.cmd_seq = 42;
  stv_cmd_execute(&c, &link, &cmd, 0, 1);
  n = drain_all(&link.txq, out, sizeof(out));
  CHECK(n == STV_ACK_FRAME_SIZE);
  memcpy(&ack, out + 4, sizeof(ack));
  CHECK(ack.cmd_seq == 42 && ack.result == STV_ACK_REFUSED_ARMED && f.ki == 0.1f && link.cfg.ki == 0.1f);

  /* correction off: the status reports it (flags bit 0) with the ARMED flag clear */
  cmd = cmd_of(STV_CMD_SET_PARAM, STV_PARAM_CORRECTION, 0.0f);
  stv_cmd_execute(&c, &link, &cmd, 0, 0);
  n = drain_all(&link.txq, out, sizeof(out));
  memcpy(&st, out + STV_ACK_FRAME_SIZE + 4, sizeof(st));
  CHECK((st.flags & STV_FLAG_NO_CORRECTION) && !(st.flags & STV_FLAG_ARMED) && st.param_gen == 2);

  /* SET_MODE text: the ack still binary, then a $STA line */
  cmd = cmd_of(STV_CMD_SET_MODE, 1, 0.0f);
  stv_cmd_execute(&c, &link, &cmd, 0, 0);
  n = drain_all(&link.txq, out, sizeof(out));
  CHECK(n > STV_ACK_FRAME_SIZE && out[0] == STV_SYNC0 && out[STV_ACK_FRAME_SIZE] == '$');
  CHECK(link.cfg.text_mode == 1 && (link.cfg.flags & STV_FLAG_TEXT_MODE));
  /* in text mode the ack is a "#ACK ..." line; SET_MODE binary switches back */
  cmd = cmd_of(STV_CMD_SET_MODE, 0, 0.0f);
  cmd.cmd_seq = 7;
  stv_cmd_execute(&c, &link, &cmd, 0, 0);
  n = drain_all(&link.txq, out, sizeof(out));
  CHECK(n > 8 && memcmp(out, "#ACK 7 4 0 5 ", 13) == 0);
  CHECK(link.cfg.text_mode == 0 && !(link.cfg.flags & STV_FLAG_TEXT_MODE));
}

static int selftest(void) {
  uint32_t r;
  test_decoder_basics();
  for (r = 0; r < 40; r++) fuzz_round(20000u);
  fuzz_random_bytes();
  test_handle();
  test_execute();
  if (checks_failed()) return 1;
  printf("ok %d (fuzz: %u intact commands, %u lost, %u cut frames completed by chance, each a command the host "
         "sent; nothing else)\n", checks, (unsigned)fuzz_intact, (unsigned)fuzz_lost, (unsigned)fuzz_extra);
  return 0;
}

static int decode_driver(void) {
  stv_cmd_dec_t d;
  stv_command_t c;
  int ch;
  stv_cmd_dec_init(&d);
  while ((ch = getchar()) != EOF)
    if (stv_cmd_dec_feed(&d, (uint8_t)ch, &c)) fwrite(&c, 1, sizeof(c), stdout);
  fprintf(stderr, "rx_ok=%u rx_bad=%u\n", (unsigned)d.rx_ok, (unsigned)d.rx_bad);
  return 0;
}

int main(int argc, char **argv) {
  if (argc == 2 && !strcmp(argv[1], "selftest")) return selftest();
  if (argc == 2 && !strcmp(argv[1], "decode")) return decode_driver();
  fprintf(stderr, "usage: %s selftest | decode < bytes > commands\n", argv[0]);
  return 2;
}

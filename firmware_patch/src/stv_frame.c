/* steval-link wire protocol v2: frame encoder and text-mode formatter (see stv_frame.h, PROTOCOL.md). */
#include "stv_frame.h"

#include <string.h>

#include "stv_crc_tables.h"

#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "stv_frame.c assumes a little-endian target (the payload structs are the wire layout)"
#endif

/* The payload structs are the wire layout: check size and every offset PROTOCOL.md fixes. */
#define STV_STATIC_ASSERT(cond, name) typedef char stv_static_assert_##name[(cond) ? 1 : -1]
STV_STATIC_ASSERT(sizeof(float) == 4, float_is_binary32);
STV_STATIC_ASSERT(sizeof(stv_attitude_t) == STV_ATTITUDE_PAYLOAD_SIZE, attitude_size);
STV_STATIC_ASSERT(offsetof(stv_attitude_t, acc_mg) == 4, att_acc);
STV_STATIC_ASSERT(offsetof(stv_attitude_t, gyro_mdps) == 16, att_gyro);
STV_STATIC_ASSERT(offsetof(stv_attitude_t, q) == 28, att_q);
STV_STATIC_ASSERT(offsetof(stv_attitude_t, thz_rad) == 44, att_thz);
STV_STATIC_ASSERT(offsetof(stv_attitude_t, seq) == 48, att_seq);
STV_STATIC_ASSERT(offsetof(stv_attitude_t, thr) == 50, att_thr);
STV_STATIC_ASSERT(sizeof(stv_status_t) == STV_STATUS_PAYLOAD_SIZE, status_size);
STV_STATIC_ASSERT(offsetof(stv_status_t, q) == 8, sta_q);
STV_STATIC_ASSERT(offsetof(stv_status_t, int_xyz) == 24, sta_int);
STV_STATIC_ASSERT(offsetof(stv_status_t, kp_ground) == 36, sta_kpg);
STV_STATIC_ASSERT(offsetof(stv_status_t, dt_s) == 48, sta_dt);
STV_STATIC_ASSERT(offsetof(stv_status_t, cyc_min) == 52, sta_cycmin);
STV_STATIC_ASSERT(offsetof(stv_status_t, baud) == 72, sta_baud);
STV_STATIC_ASSERT(offsetof(stv_status_t, cyc_n) == 76, sta_cycn);
STV_STATIC_ASSERT(offsetof(stv_status_t, min_thr) == 78, sta_minthr);
STV_STATIC_ASSERT(offsetof(stv_status_t, flags) == 80, sta_flags);
STV_STATIC_ASSERT(offsetof(stv_status_t, queue_peak) == 82, sta_peak);
STV_STATIC_ASSERT(offsetof(stv_status_t, fw_version) == 84, sta_fw);
STV_STATIC_ASSERT(offsetof(stv_status_t, fc_every) == 86, sta_fc_every);
STV_STATIC_ASSERT(offsetof(stv_status_t, param_gen) == 87, sta_param_gen);
STV_STATIC_ASSERT(sizeof(stv_flight_t) == STV_FLIGHT_PAYLOAD_SIZE, flight_size);
STV_STATIC_ASSERT(offsetof(stv_flight_t, euler_rc_rad) == 4, fc_rc_rad);
STV_STATIC_ASSERT(offsetof(stv_flight_t, rc) == 16, fc_rc);
STV_STATIC_ASSERT(offsetof(stv_flight_t, outer_s1) == 24, fc_s1);
STV_STATIC_ASSERT(offsetof(stv_flight_t, inner_s2) == 36, fc_s2);
STV_STATIC_ASSERT(offsetof(stv_flight_t, motor_pwm) == 48, fc_motor);
STV_STATIC_ASSERT(offsetof(stv_flight_t, vbat_v) == 64, fc_vbat);
STV_STATIC_ASSERT(offsetof(stv_flight_t, fc_flags) == 68, fc_flags);
STV_STATIC_ASSERT(offsetof(stv_flight_t, fc_every) == 70, fc_every);
STV_STATIC_ASSERT(sizeof(stv_ack_t) == STV_ACK_PAYLOAD_SIZE, ack_size);
STV_STATIC_ASSERT(offsetof(stv_ack_t, step) == 4, ack_step);
STV_STATIC_ASSERT(offsetof(stv_ack_t, rx_bad) == 10, ack_rx_bad);
STV_STATIC_ASSERT(sizeof(stv_command_t) == STV_COMMAND_PAYLOAD_SIZE, command_size);
STV_STATIC_ASSERT(offsetof(stv_command_t, value) == 4, cmd_value);

#define STV_VT(type) ((uint32_t)((STV_VERSION << 4) | (type)))
/* Sync, VT and LEN as one little-endian word. */
#define STV_HEADER_WORD(type, len) \
  (STV_SYNC0 | (STV_SYNC1 << 8) | (STV_VT(type) << 16) | ((uint32_t)(len) << 24))

#if defined(__GNUC__) && !defined(__clang__)
#define STV_UNROLL(n) _Pragma("GCC unroll 32")
#else
#define STV_UNROLL(n)
#endif

static inline uint32_t load32(const void *p) {
  uint32_t v;
  memcpy(&v, p, 4); /* one LDR (unaligned allowed on Cortex-M4) */
  return v;
}

static inline void store32(void *p, uint32_t v) { memcpy(p, &v, 4); }

/* Advance the (non-inverted) CRC-32 register over four bytes given as a little-endian word. */
static inline uint32_t crc_word(uint32_t crc, uint32_t word_le) {
  uint32_t x = crc ^ word_le;
  return stv_crc32_t3[x & 0xFFu] ^ stv_crc32_t2[(x >> 8) & 0xFFu] ^ stv_crc32_t1[(x >> 16) & 0xFFu] ^
         stv_crc32_t0[x >> 24];
}

static inline uint32_t crc_byte(uint32_t crc, uint32_t b) { return (crc >> 8) ^ stv_crc32_t0[(crc ^ b) & 0xFFu]; }

/* CRC register after VT and LEN (both constant per fixed-size type: folded by the compiler). */
static inline uint32_t crc_header(uint32_t type, uint32_t len) {
  return crc_byte(crc_byte(0xFFFFFFFFu, STV_VT(type)), len);
}

uint32_t stv_crc32_update(uint32_t crc32, const uint8_t *data, size_t len) {
  uint32_t crc = ~crc32;
  while (len >= 4u) {
    crc = crc_word(crc, load32(data));
    data += 4;
    len -= 4u;
  }
  while (len--) crc = crc_byte(crc, *data++);
  return ~crc;
}

/* Frame of a fixed-size payload of `nwords` words: header word, payload words with the CRC, CRC. */
static inline size_t encode_fixed(uint8_t *out, const void *payload, uint32_t type, uint32_t nwords) {
  const uint8_t *src = (const uint8_t *)payload;
  uint8_t *dst = out + STV_HEADER_SIZE;
  uint32_t crc = crc_header(type, nwords * 4u);
  uint32_t i;
  store32(out, STV_HEADER_WORD(type, nwords * 4u));
  STV_UNROLL(32)
  for (i = 0; i < nwords; i++) {
    uint32_t w = load32(src + 4u * i);
    store32(dst + 4u * i, w);
    crc = crc_word(crc, w);
  }
  store32(dst + 4u * nwords, ~crc);
  return STV_HEADER_SIZE + 4u * nwords + STV_CRC_SIZE;
}

size_t stv_encode_attitude(uint8_t *out, const stv_attitude_t *att) {
  return encode_fixed(out, att, STV_TYPE_ATTITUDE, STV_ATTITUDE_PAYLOAD_SIZE / 4u);
}

size_t stv_encode_status(uint8_t *out, const stv_status_t *st) {
  return encode_fixed(out, st, STV_TYPE_STATUS, STV_STATUS_PAYLOAD_SIZE / 4u);
}

size_t stv_encode_flight(uint8_t *out, const stv_flight_t *fc) {
  return encode_fixed(out, fc, STV_TYPE_FLIGHT, STV_FLIGHT_PAYLOAD_SIZE / 4u);
}

size_t stv_encode_ack(uint8_t *out, const stv_ack_t *ack) {
  return encode_fixed(out, ack, STV_TYPE_ACK, STV_ACK_PAYLOAD_SIZE / 4u);
}

size_t stv_encode_command(uint8_t *out, const stv_command_t *cmd) {
  return encode_fixed(out, cmd, STV_TYPE_COMMAND, STV_COMMAND_PAYLOAD_SIZE / 4u);
}

size_t stv_encode_frame(uint8_t *out, uint8_t type, const uint8_t *payload, size_t len) {
  uint32_t crc;
  if (len > 255u) len = 255u;
  out[0] = STV_SYNC0;
  out[1] = STV_SYNC1;
  out[2] = (uint8_t)STV_VT(type & 0x0Fu);
  out[3] = (uint8_t)len;
  if (len) memmove(out + STV_HEADER_SIZE, payload, len);
  crc = stv_crc32_update(0u, out + 2, len + 2u);
  out[STV_HEADER_SIZE + len] = (uint8_t)crc;
  out[STV_HEADER_SIZE + len + 1u] = (uint8_t)(crc >> 8);
  out[STV_HEADER_SIZE + len + 2u] = (uint8_t)(crc >> 16);
  out[STV_HEADER_SIZE + len + 3u] = (uint8_t)(crc >> 24);
  return STV_HEADER_SIZE + len + STV_CRC_SIZE;
}

/* Text mode ------------------------------------------------------------------------------------------------ */

int32_t stv_f2i_trunc(float x) {
  if (!(x == x)) return 0; /* NaN */
  if (x >= 2147483520.0f) return INT32_MAX;  /* largest float below 2^31 */
  if (x <= -2147483648.0f) return INT32_MIN;
  return (int32_t)x;
}

static char *put_u32(char *p, uint32_t v) {
  char tmp[10];
  unsigned n = 0;
  do {
    tmp[n++] = (char)('0' + v % 10u);
    v /= 10u;
  } while (v);
  while (n) *p++ = tmp[--n];
  return p;
}

static char *put_i32(char *p, int32_t v) {
  if (v < 0) {
    *p++ = '-';
    return put_u32(p, 0u - (uint32_t)v);
  }
  return put_u32(p, (uint32_t)v);
}

/* Append "*HH\r\n" with the XOR of line[1 .. p-1] (the bytes between '$' and '*'). */
static size_t finish_line(char *line, char *p) {
  static const char hex[] = "0123456789ABCDEF";
  unsigned x = 0;
  const char *c;
  for (c = line + 1; c < p; c++) x ^= (unsigned char)*c;
  *p++ = '*';
  *p++ = hex[(x >> 4) & 0xFu];
  *p++ = hex[x & 0xFu];
  *p++ = '\r';
  *p++ = '\n';
  return (size_t)(p - line);
}

#define STV_RAD_TO_MDEG 57295.78f

size_t stv_format_att_line(char *out, const stv_att_line_t *v) {
  char *p = out;
  int i;
  memcpy(p, "$ATT,", 5);
  p += 5;
  p = put_u32(p, v->step);
  *p++ = ',';
  p = put_u32(p, v->t_us / 1000u);
  *p++ = ',';
  p = put_i32(p, v->thr);
  *p++ = ',';
  p = put_i32(p, stv_f2i_trunc(v->thx_rad * STV_RAD_TO_MDEG));
  *p++ = ',';
  p = put_i32(p, stv_f2i_trunc(v->thy_rad * STV_RAD_TO_MDEG));
  *p++ = ',';
  p = put_i32(p, stv_f2i_trunc(v->thz_rad * STV_RAD_TO_MDEG));
  for (i = 0; i < 3; i++) {
    *p++ = ',';
    p = put_i32(p, stv_f2i_trunc(v->acc_mg[i]));
  }
  for (i = 0; i < 3; i++) {
    *p++ = ',';
    p = put_i32(p, stv_f2i_trunc(v->gyro_mdps[i]));
  }
  return finish_line(out, p);
}

size_t stv_format_sta_line(char *out, const stv_status_t *st) {
  char *p = out;
  memcpy(p, "$STA,", 5);
  p += 5;
  p = put_u32(p, st->step);
  *p++ = ',';
  p = put_u32(p, st->t_us / 1000u);
  *p++ = ',';
  p = put_u32(p, st->cyc_min);
  *p++ = ',';
  p = put_u32(p, st->cyc_mean);
  *p++ = ',';
  p = put_u32(p, st->cyc_max);
  *p++ = ',';
  p = put_u32(p, st->cyc_n);
  *p++ = ',';
  p = put_u32(p, st->tx_dropped);
  *p++ = ',';
  p = put_u32(p, st->flags);
  *p++ = ',';
  p = put_i32(p, stv_f2i_trunc(st->ki * 1000000.0f + (st->ki >= 0.0f ? 0.5f : -0.5f)));
  return finish_line(out, p);
}

/* steval-link TX queue (see stv_txq.h). */
#include "stv_txq.h"

#include <string.h>

#define MASK (STV_TXQ_SIZE - 1u)

void stv_txq_init(stv_txq_t *q) {
  q->head = 0;
  q->tail = 0;
  q->dropped = 0;
  q->peak = 0;
}

/* Word-wise copy (unaligned words are fine on Cortex-M4 and x86); written out so no libc memcpy is called. */
static inline void copy_bytes(uint8_t *dst, const uint8_t *src, uint32_t n) {
  while (n >= 4u) {
    uint32_t w;
    memcpy(&w, src, 4);
    memcpy(dst, &w, 4);
    src += 4;
    dst += 4;
    n -= 4u;
  }
  while (n--) *dst++ = *src++;
}

int stv_txq_push_keep(stv_txq_t *q, const uint8_t *src, uint32_t len, uint32_t keep_free) {
  uint32_t h = q->head;
  uint32_t used = h - q->tail;
  uint32_t idx, run;
  if (len + keep_free > STV_TXQ_SIZE - used) {
    q->dropped++;
    return 0;
  }
  idx = h & MASK;
  run = STV_TXQ_SIZE - idx;
  if (len <= run) {
    copy_bytes(&q->buf[idx], src, len);
  } else {
    copy_bytes(&q->buf[idx], src, run);
    copy_bytes(&q->buf[0], src + run, len - run);
  }
  stv_txq_commit(q, len);
  return 1;
}

uint8_t *stv_txq_reserve(stv_txq_t *q, uint32_t len, uint32_t keep_free) {
  uint32_t h = q->head;
  uint32_t idx = h & MASK;
  if (len + keep_free > STV_TXQ_SIZE - (h - q->tail) || len > STV_TXQ_SIZE - idx) return 0;
  return &q->buf[idx];
}

void stv_txq_commit(stv_txq_t *q, uint32_t len) {
  uint32_t used;
  __asm__ volatile("" ::: "memory"); /* bytes in place before the consumer can see them */
  q->head += len;
  used = q->head - q->tail;
  if (used > q->peak) q->peak = used;
}

uint32_t stv_txq_pop(stv_txq_t *q, uint8_t *dst, uint32_t max) {
  uint32_t n = 0;
  while (n < max) {
    uint32_t len;
    const uint8_t *p = stv_txq_peek(q, &len);
    if (len == 0) break;
    if (len > max - n) len = max - n;
    memcpy(dst + n, p, len);
    stv_txq_consume(q, len);
    n += len;
  }
  return n;
}

uint32_t stv_txq_take_peak(stv_txq_t *q) {
  uint32_t p = q->peak;
  q->peak = stv_txq_used(q);
  return p;
}

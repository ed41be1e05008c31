/* steval-link TX queue: a byte ring buffer between the main loop (producer) and the UART interrupt (consumer).
 *
 * Lock-free for one producer and one consumer: the producer only writes `head`, the consumer only `tail`; both
 * run free (uint32_t) and are masked on use. A frame goes in whole or not at all: when it does not fit it is
 * dropped and counted, and the producer returns at once (the main loop never waits for the UART).
 * Pure C99 (no hardware access): the same code runs in the host tests and on the Cortex-M4.
 */
#ifndef STV_TXQ_H
#define STV_TXQ_H

#include <stdint.h>

#include "stv_config.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
  volatile uint32_t head; /* bytes ever written (producer) */
  volatile uint32_t tail; /* bytes ever read (consumer) */
  uint32_t dropped;       /* frames refused because they did not fit (cumulative) */
  uint32_t peak;          /* most bytes waiting since the last stv_txq_take_peak() */
  uint8_t buf[STV_TXQ_SIZE];
} stv_txq_t;

void stv_txq_init(stv_txq_t *q);

/* Bytes waiting. */
static inline uint32_t stv_txq_used(const stv_txq_t *q) { return q->head - q->tail; }

/* Append len bytes as one unit if at least `keep_free` bytes stay free after them. Returns 1, or 0 (and counts one
 * dropped frame) when they do not fit. The reserve gives status frames priority: under overload attitude and text
 * frames leave room for the next status, so the host still learns how many frames were dropped. */
int stv_txq_push_keep(stv_txq_t *q, const uint8_t *src, uint32_t len, uint32_t keep_free);

/* Append len bytes as one unit (no reserve). */
static inline int stv_txq_push(stv_txq_t *q, const uint8_t *src, uint32_t len) {
  return stv_txq_push_keep(q, src, len, 0u);
}

/* Consumer: up to max bytes into dst; returns how many. */
uint32_t stv_txq_pop(stv_txq_t *q, uint8_t *dst, uint32_t max);

/* Zero-copy enqueue: where `len` bytes can be written in one piece at the head with `keep_free` bytes left free,
 * returns the place (the caller writes the frame there, then calls stv_txq_commit); else NULL, and nothing is
 * counted (the caller falls back to stv_txq_push_keep, which copies around the wrap or drops and counts). */
uint8_t *stv_txq_reserve(stv_txq_t *q, uint32_t len, uint32_t keep_free);
void stv_txq_commit(stv_txq_t *q, uint32_t len);

/* Consumer, one byte (for a TXE interrupt): returns 1 and the byte in *b, or 0 when empty. */
static inline int stv_txq_pop_byte(stv_txq_t *q, uint8_t *b) {
  uint32_t t = q->tail;
  if (q->head == t) return 0;
  *b = q->buf[t & (STV_TXQ_SIZE - 1u)];
  __asm__ volatile("" ::: "memory"); /* read the byte before releasing its slot */
  q->tail = t + 1u;
  return 1;
}

/* Consumer, zero-copy (for DMA): the contiguous run of waiting bytes starting at the tail. */
static inline const uint8_t *stv_txq_peek(const stv_txq_t *q, uint32_t *len) {
  uint32_t t = q->tail, used = q->head - t, idx = t & (STV_TXQ_SIZE - 1u), run = STV_TXQ_SIZE - idx;
  *len = used < run ? used : run;
  return &q->buf[idx];
}

/* Consumer: release n bytes returned by stv_txq_peek. */
static inline void stv_txq_consume(stv_txq_t *q, uint32_t n) {
  __asm__ volatile("" ::: "memory");
  q->tail += n;
}

/* Peak fill since the last call, then restart the peak from the current fill. */
uint32_t stv_txq_take_peak(stv_txq_t *q);

#ifdef __cplusplus
}
#endif

#endif /* STV_TXQ_H */

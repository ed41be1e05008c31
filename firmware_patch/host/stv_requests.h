/* Frame requests -> frames, through the firmware's encoder and TX queue (host tool and emulator harness).
 *
 * A request is `u8 type, u8 len, payload[len]`, the payload being exactly PROTOCOL.md's payload of that type
 * (1 attitude: 52 bytes, 2 status: 88 bytes, 3 text: 0..255 bytes). Each request is parsed field by field into the
 * C structs, sent with stv_send_attitude/stv_send_status/stv_send_text as the firmware sends it, and the queue is
 * drained into `sink` as a UART would drain it.
 */
#ifndef STV_REQUESTS_H
#define STV_REQUESTS_H

#include <stddef.h>
#include <stdint.h>

#include "stv_link.h"

typedef void (*stv_sink_fn)(void *ctx, const uint8_t *data, uint32_t len);

enum {
  STV_REQ_OK = 0,
  STV_REQ_TRUNCATED = 1,   /* the input ends inside a request */
  STV_REQ_BAD_TYPE = 2,    /* type not 1, 2, 3, 4, 5 or 8 */
  STV_REQ_BAD_LENGTH = 3,  /* a fixed-size type with another payload length */
  STV_REQ_DROPPED = 4      /* the queue refused a frame (cannot happen while it is drained after each request) */
};

/* Run the requests in in[0..n-1]. *done receives the bytes of whole requests processed. Returns STV_REQ_*. */
int stv_run_requests(stv_txq_t *q, const uint8_t *in, size_t n, size_t *done, stv_sink_fn sink, void *ctx);

#endif /* STV_REQUESTS_H */

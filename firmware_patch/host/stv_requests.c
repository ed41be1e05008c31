/* Frame requests -> frames (see stv_requests.h). */
#include "stv_requests.h"

#include <string.h>

/* The payload structs are the wire layout on a little-endian host (stv_frame.c checks it): copy the bytes. */
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
    if (type == STV_TYPE_TEXT) {
      if (stv_send_text(q, payload, len)) rc = STV_REQ_DROPPED;
    } else if (type == STV_TYPE_ATTITUDE || type == STV_TYPE_STATUS || type == STV_TYPE_FLIGHT ||
               type == STV_TYPE_ACK || type == STV_TYPE_COMMAND) {
      union {
        stv_attitude_t a;
        stv_status_t s;
        stv_flight_t f;
        stv_ack_t k;
        stv_command_t c;
      } u;
      static const uint8_t size_of[9] = {0, STV_ATTITUDE_PAYLOAD_SIZE, STV_STATUS_PAYLOAD_SIZE, 0,
                                         STV_FLIGHT_PAYLOAD_SIZE, STV_ACK_PAYLOAD_SIZE, 0, 0,
                                         STV_COMMAND_PAYLOAD_SIZE};
      int ok;
      if (len != size_of[type]) {
        rc = STV_REQ_BAD_LENGTH;
        break;
      }
      memcpy(&u, payload, len);
      if (type == STV_TYPE_ATTITUDE) {
        ok = stv_send_attitude(q, &u.a);
      } else if (type == STV_TYPE_STATUS) {
        ok = stv_send_status(q, &u.s);
      } else if (type == STV_TYPE_FLIGHT) {
        ok = stv_send_flight(q, &u.f);
      } else if (type == STV_TYPE_ACK) {
        ok = stv_send_ack(q, &u.k);
      } else {
        /* host -> drone commands, encoded by the same code (for the host tests and the emulated host) */
        union {
          uint32_t align;
          uint8_t b[STV_COMMAND_FRAME_SIZE];
        } f;
        stv_encode_command(f.b, &u.c);
        ok = stv_txq_push(q, f.b, STV_COMMAND_FRAME_SIZE);
      }
      if (!ok) rc = STV_REQ_DROPPED;
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

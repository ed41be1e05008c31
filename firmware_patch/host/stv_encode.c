/* stv_encode: frame requests on stdin -> wire-protocol v2 frames on stdout, made by the firmware's C encoder and
 * TX queue (firmware_patch/src). Used to produce the bundled recordings and as a C -> Python conformance check.
 *
 *   <frame requests> | firmware_patch/host/stv_encode > frames.bin
 *
 * Input: records `u8 type, u8 len, payload[len]` (payload = PROTOCOL.md payload of type 1/2/3/4/5/8). Exit 0 on success;
 * 2 with one line on stderr for malformed input (all frames of the requests before it are already written).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "stv_requests.h"

typedef struct {
  int failed;
} out_ctx_t;

static void write_out(void *ctx, const uint8_t *data, uint32_t len) {
  out_ctx_t *o = (out_ctx_t *)ctx;
  if (!o->failed && fwrite(data, 1, len, stdout) != len) o->failed = 1;
}

int main(int argc, char **argv) {
  static stv_txq_t q;
  static uint8_t buf[1 << 16];
  size_t have = 0, offset = 0;
  out_ctx_t out = {0};
  int rc = STV_REQ_OK;
  if (argc > 1) {
    fprintf(stderr,
            "usage: %s < requests > frames\n"
            "Reads frame requests (u8 type, u8 len, payload[len]; PROTOCOL.md payloads) on stdin and writes the\n"
            "frames the firmware's C encoder makes of them on stdout.\n",
            argv[0]);
    return (argc == 2 && (!strcmp(argv[1], "-h") || !strcmp(argv[1], "--help"))) ? 0 : 2;
  }
  stv_txq_init(&q);
  for (;;) {
    size_t got = fread(buf + have, 1, sizeof(buf) - have, stdin);
    size_t done = 0;
    int eof = got == 0;
    have += got;
    rc = stv_run_requests(&q, buf, have, &done, write_out, &out);
    offset += done;
    memmove(buf, buf + done, have - done);
    have -= done;
    if (rc == STV_REQ_TRUNCATED && !eof) continue;
    if (rc != STV_REQ_OK || eof) break;
  }
  if (fflush(stdout) != 0 || out.failed) {
    fprintf(stderr, "stv_encode: cannot write the frames to stdout\n");
    return 2;
  }
  if (rc == STV_REQ_TRUNCATED && have == 0) rc = STV_REQ_OK;
  switch (rc) {
    case STV_REQ_OK:
      return 0;
    case STV_REQ_TRUNCATED:
      fprintf(stderr, "stv_encode: input ends inside the request at byte %zu\n", offset);
      return 2;
    case STV_REQ_BAD_TYPE:
      fprintf(stderr, "stv_encode: request at byte %zu has unknown frame type %u (expected 1, 2 or 3)\n", offset,
              buf[0]);
      return 2;
    case STV_REQ_BAD_LENGTH:
      fprintf(stderr, "stv_encode: request at byte %zu: type %u needs a %u-byte payload, got %u bytes\n", offset,
              buf[0], buf[0] == 1 ? 52u : 88u, buf[1]);
      return 2;
    default:
      fprintf(stderr, "stv_encode: the TX queue dropped a frame at byte %zu\n", offset);
      return 2;
  }
}

/* Bare-metal harness: the firmware's encoder and TX queue, cross-compiled for the Cortex-M4 and run under a CPU
 * emulator (unicorn) by tests/test_firmware_emu.py, which writes frame requests (host/stv_requests.h) into
 * emu_in, calls emu_run with LR = emu_halt, and decodes emu_out in Python. No startup code: the test loads the
 * sections at their run addresses and sets SP.
 */
#include <stdint.h>

#include "stv_requests.h"

#define EMU_IN_SIZE 16384u
#define EMU_OUT_SIZE 32768u

uint8_t emu_in[EMU_IN_SIZE];
volatile uint32_t emu_in_len;
uint8_t emu_out[EMU_OUT_SIZE];
volatile uint32_t emu_out_len;
volatile int32_t emu_rc;

static stv_txq_t emu_q;

void emu_run(void);
void emu_halt(void);

static void sink(void *ctx, const uint8_t *data, uint32_t len) {
  uint32_t i, n = emu_out_len;
  (void)ctx;
  for (i = 0; i < len && n < EMU_OUT_SIZE; i++) emu_out[n++] = data[i];
  emu_out_len = n;
}

void emu_run(void) {
  size_t done = 0;
  emu_out_len = 0;
  stv_txq_init(&emu_q);
  emu_rc = stv_run_requests(&emu_q, emu_in, emu_in_len, &done, sink, 0);
  emu_halt();
}

__attribute__((noinline, used)) void emu_halt(void) {
  for (;;) __asm__ volatile("bkpt #0");
}

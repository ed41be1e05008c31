/* Bare-metal harness: the firmware's encoder and TX queue, cross-compiled for the Cortex-M4 and run under a CPU
 * emulator (unicorn) by tests/test_firmware_emu.py, which writes frame requests (host/stv_requests.h) into
 * emu_in, calls emu_run with LR = emu_halt, and decodes emu_out in Python. No startup code: the test loads the
 * sections at their run addresses and sets SP.
 */
#include <stdint.h>
#include <string.h>

#include "stv_requests.h"
#include "stv_stock_config.h"

#define EMU_IN_SIZE 16384u
#define EMU_OUT_SIZE 32768u

uint8_t emu_in[EMU_IN_SIZE];
volatile uint32_t emu_in_len;
uint8_t emu_out[EMU_OUT_SIZE];
volatile uint32_t emu_out_len;
volatile int32_t emu_rc;

static stv_txq_t emu_q;

void emu_run(void);
void emu_run_link(void);
void emu_run_text(void);
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

/* The main-loop side as the firmware runs it: emu_in holds emu_in_len / 40 steps of
 * f32 acc[3], gyro[3], q[4] (bytes 0..39); binary mode, status every 162 steps, queue drained after each step. */
void emu_run_link(void) {
  static stv_link_t link;
  static const float zero = 0.0f;
  stv_link_config_t c = stv_stock_config();
  uint32_t i, n = emu_in_len / 40u, cyc = 1000u;
  for (i = 0; i < 4; i++) c.q_state[i] = &zero;
  for (i = 0; i < 3; i++) c.int_state[i] = &zero;
  emu_out_len = 0;
  stv_link_init(&link, &c, cyc);
  for (i = 0; i < n; i++) {
    const float *v = (const float *)(const void *)(emu_in + 40u * i);
    float eul[3] = {0.0f, 0.0f, v[2]};
    cyc += 519960u;
    stv_link_step_begin(&link, cyc, (int16_t)i);
    stv_link_step_end(&link, cyc + 5000u, v, v + 3, v + 6, eul);
    {
      uint32_t len;
      const uint8_t *p;
      while ((p = stv_txq_peek(&link.txq, &len)), len) {
        sink(0, p, len);
        stv_txq_consume(&link.txq, len);
      }
    }
  }
  emu_rc = (int32_t)link.txq.dropped;
  emu_halt();
}

/* Text mode on the target (float -> integer conversions in hardware): emu_in holds emu_in_len / 48 lines of
 * u32 step, u32 t_us, i32 thr, f32 thx, thy, thz, acc[3], gyro[3]; the $ATT lines go to emu_out. */
void emu_run_text(void) {
  uint32_t i, n = emu_in_len / 48u;
  emu_out_len = 0;
  for (i = 0; i < n; i++) {
    const uint8_t *p = emu_in + 48u * i;
    stv_att_line_t v;
    int32_t thr;
    char line[STV_TEXT_LINE_MAX];
    memcpy(&v.step, p, 4);
    memcpy(&v.t_us, p + 4, 4);
    memcpy(&thr, p + 8, 4);
    v.thr = (int16_t)thr;
    memcpy(&v.thx_rad, p + 12, 4);
    memcpy(&v.thy_rad, p + 16, 4);
    memcpy(&v.thz_rad, p + 20, 4);
    memcpy(v.acc_mg, p + 24, 12);
    memcpy(v.gyro_mdps, p + 36, 12);
    sink(0, (const uint8_t *)line, (uint32_t)stv_format_att_line(line, &v));
  }
  emu_halt();
}

__attribute__((noinline, used)) void emu_halt(void) {
  for (;;) __asm__ volatile("bkpt #0");
}

/* The emulated board's hot path in C (board/native.py; the model: the board package's docstring). The Python models
 * translated (usart.py, timer.py, scs.py, cpu.py, core.py, memory_map.py's ADC1): the same registers at the same
 * instruction counts. Python owns the state (a core_t allocated with ctypes, mirrored in board/native.py), registers
 * these functions with unicorn's C API and hands over its entry points (no unicorn header here). Python is called
 * back (py_event) for TIM9 updates without a plan, a full output buffer, sensor reads without an image, code sites. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#if defined(_WIN32)
#define EXPORT __declspec(dllexport)
#else
#define EXPORT __attribute__((visibility("default")))
#endif
#if defined(_MSC_VER)
#define COLD __declspec(noinline)
#else
#define COLD __attribute__((noinline, cold))
#endif

typedef int (*emu_start_t)(void *uc, uint64_t begin, uint64_t until, uint64_t timeout, size_t count);
typedef int (*emu_stop_t)(void *uc);
typedef int (*reg_rw_t)(void *uc, int regid, void *value);
typedef int (*reg_batch_t)(void *uc, int *regs, void **vals, int count);
typedef int (*py_event_t)(int64_t kind, int64_t arg);

#define RAM_BASE 0x20000000u
#define RAM_SIZE 0x10000u
#define FLASH_SIZE 0x40000u
#define IRQ_BASE 16
#define EXC_SYSTICK 15
#define IRQ_USART1 37
#define FP_FRAME_WORDS 26
#define FRAME_READS 17
#define FRAME_WRITES 15
#define NONE (-1)

/* py_event kinds: TIM9's update event (the tick observers), drain the output buffer, a Sensor_IO_Read the images
 * cannot answer, a Python code hook (arg: its index; hook_addr, hook_size), an access to a mirrored page the mirror
 * cannot serve, a bit-band access outside USART1 (hook_addr: offset in the alias, hook_size: bytes), a full mark
 * buffer */
enum { EV_TICK = 1, EV_OUT_FULL, EV_SENSOR, EV_CODE, EV_MMIO, EV_BITBAND, EV_MARKS_FULL };
/* fault codes (Python words the message) */
enum { F_PYTHON = 1, F_STACK, F_RETURN, F_CPU_EXC, F_EMU };

/* USART bits: SR, CR1 */
enum { SR_TXE = 0x80, SR_TC = 0x40, SR_RXNE = 0x20, SR_ORE = 0x08 };
enum { CR1_UE = 0x2000, CR1_TXEIE = 0x80, CR1_TCIE = 0x40, CR1_RXNEIE = 0x20, CR1_RE = 0x04 };

#define MAX_SITES 512
#define FLASH_BASE 0x08000000u
/* code site kinds */
enum { K_UNMASK = 1, K_IDLE, K_WFI, K_SENSOR, K_PY, K_MARK };
#define MAX_IDLE 4
#define MAX_MIRROR 10
#define MAX_IDLE_WORDS 8
#define POLL_STACK 256
#define MAX_MARK_RANGES 8
#define MARK_WORDS 6

/* A Python peripheral's page with reads served in C: the words marked served hold what Python's model reads
 * (Python keeps them current); other reads and every write go to Python. */
typedef struct {
  void *core;
  int64_t page;
  uint32_t vals[256];
  uint8_t served[256];
} mirror_t;

/* A general-purpose timer (TIM9, TIM2, TIM4): registers by word, the next update event, the update count. */
typedef struct {
  void *core;
  int64_t irq, next, updates, first_update;
  uint32_t regs[256];
} ctimer_t;

typedef struct {
  /* the counter: n instructions in this slice, stop when n reaches limit */
  uint64_t n, limit;
  /* unicorn */
  void *uc;
  void *emu_start, *emu_stop, *reg_read, *reg_write, *reg_read_batch, *reg_write_batch;
  void *py_event;
  uint8_t *ram, *flash;
  /* register ids: sp lr pc xpsr primask r0 r1 r2 r3; the frame (FRAME_READS: r0-r3 r12 lr pc xpsr d0-d7 fpscr)
   * and its write-back (FRAME_WRITES: the same without pc and xpsr) */
  int64_t rid[9];
  int32_t frame_ids[26], wframe_ids[24];
  /* clock */
  int64_t now, slice_start, skip_base, run_end, next_event, max_slice;
  int64_t instructions, skipped, slices, fault, fault_arg, resumed_idle;
  /* NVIC */
  uint64_t pending[4], enabled[4];
  uint8_t prio[256];
  int64_t prigroup, n_active, active[64], counts[256];
  int64_t exc_instructions, exc_started, vtor;
  /* SysTick */
  int64_t systick_next, systick_period, systick_tickint, countflag;
  /* TIM9, TIM2, TIM4 (only the first two have update events scheduled, as in the Python board) */
  ctimer_t tim[3];
  /* USART1: registers by word (SR's stored bits, BRR, CR1...), TX, RX */
  uint32_t uregs[256];
  int64_t dr_full, shift_done, shift_byte, tc;
  int64_t rx_done, rx_line_free, rx_dr, rx_last, rx_ore, ore_sr_read, rx_received, rx_overruns, rx_lost;
  int64_t *rx_t; uint8_t *rx_b; int64_t rx_cap, rx_head, rx_len;
  int64_t *rxlog_t; uint8_t *rxlog_b; int64_t rxlog_cap, rxlog_len;
  int64_t *out_t; uint8_t *out_b; int64_t out_cap, out_len;
  /* idle sites: address, RAM words (offset, bytes) that must be 0, caller range for LR (lo == hi: any) */
  int64_t n_idle, idle_addr[MAX_IDLE], idle_n_words[MAX_IDLE], idle_off[MAX_IDLE][MAX_IDLE_WORDS],
      idle_size[MAX_IDLE][MAX_IDLE_WORDS], idle_lo[MAX_IDLE], idle_hi[MAX_IDLE];
  /* sensors: 128-byte images of devices 0..2; device 0 (LSM6DSL) valid for TIM9 update sensor_valid only */
  uint8_t sensor_img[3][128];
  int64_t sensor_fast[3], sensor_valid, sensor_reads;
  /* code sites, sorted by address (stable): kind, argument; a bitmap of the flash half-words that have one */
  int64_t n_sites, site_addr[MAX_SITES], site_kind[MAX_SITES], site_arg[MAX_SITES], hook_addr, hook_size;
  uint8_t site_map[FLASH_SIZE / 16];
  /* mirrored pages; the access handed to Python (hook_addr: offset, hook_size: bytes) */
  mirror_t mirror[MAX_MIRROR];
  int64_t mmio_write, mmio_value;
  /* the TXE/TC poll skip: the address of the instruction reading SR, a count of everything that
   * can change what a poll loop sees (events, exceptions, MMIO, Python), the last USART1 SR read in thread mode
   * (where, when, the value, the epoch, r0-r12 sp lr xpsr, the stack's top POLL_STACK bytes), instructions skipped */
  int64_t poll_skip, last_pc, io_epoch, poll_pc, poll_now, poll_sr, poll_epoch, polled, poll_stack_len;
  int32_t poll_ids[16];
  uint32_t poll_regs[16];
  uint8_t poll_stack[POLL_STACK];
  /* the SCS's mirror (its page number, -1: none) and DWT CYCCNT while counting: now - cyccnt_base */
  int64_t scs_page, cyccnt_on, cyccnt_base;
  /* USART1's base address (bit-band accesses to it are served here) */
  int64_t usart_base;
  /* TIM9 updates plan_u0 .. plan_u0 + plan_n - 1 planned by Python (while now < plan_until): the LSM6DSL's outputs
   * 0x22..0x2D (12 bytes an update) and plan_len bytes an update written to RAM at plan_addr; other updates call
   * Python (EV_TICK) */
  uint8_t *plan_img, *plan_ram;
  int64_t plan_u0, plan_n, plan_until, plan_addr, plan_len;
  /* ADC1's mirror (-1: none), whose SR and CR2 words C owns, and the reading its DR returns */
  int64_t adc_page, adc_dr;
  /* marks (K_MARK sites; arg: the mark's kind), read by Python after the run: MARK_WORDS words each (kind, now,
   * instructions, exception instructions, CYCCNT, TIM9 updates) and mark_bytes RAM bytes each (the ranges at RAM
   * offsets mark_off, mark_size bytes, in order); CYCCNT is cyccnt_frozen while DWT is not counting */
  int64_t *mark_w;
  uint8_t *mark_b;
  int64_t mark_cap, mark_len, mark_bytes, n_mark_ranges, mark_off[MAX_MARK_RANGES], mark_size[MAX_MARK_RANGES];
  int64_t cyccnt_frozen;
} core_t;

EXPORT int64_t core_sizeof(void) { return (int64_t)sizeof(core_t); }

/* ---- helpers ---------------------------------------------------------------------------------------------- */

static inline void touched(core_t *s) { s->io_epoch++; }
static inline void sync_now(core_t *s) { s->now = s->slice_start + (int64_t)s->n + s->skip_base; }
static inline int64_t instructions_now(core_t *s) { return s->instructions + (int64_t)s->n; }

/* the size bytes at off & 3 of a 32-bit register (a byte, half-word or word read) */
static inline uint64_t lanes(uint32_t w, uint64_t off, unsigned size) {
  return (w >> ((off & 3) * 8)) & (size >= 4 ? 0xFFFFFFFFull : ((1ull << (8 * size)) - 1));
}

/* a byte or half-word write merged into the register word it modifies (old) */
static inline uint32_t merged(uint32_t old, uint64_t off, unsigned size, uint64_t value) {
  if (size == 4) return (uint32_t)value;
  uint32_t sh = (off & 3) * 8, mask = (uint32_t)(((1ull << (8 * size)) - 1) << sh);
  return (old & ~mask) | (((uint32_t)value << sh) & mask);
}

/* an access handed to Python (py_event kind, arg): hook_addr, hook_size, mmio_write, mmio_value; a read's value */
static uint64_t ask_python(core_t *s, int64_t kind, int64_t arg, uint64_t off, unsigned size, int write,
                           uint64_t value) {
  sync_now(s);
  s->hook_addr = (int64_t)off;
  s->hook_size = size;
  s->mmio_write = write;
  s->mmio_value = (int64_t)value;
  ((py_event_t)s->py_event)(kind, arg);
  return (uint64_t)s->mmio_value;
}

static inline uint32_t reg_get(core_t *s, int64_t id) {
  uint32_t v = 0;
  ((reg_rw_t)s->reg_read)(s->uc, (int)id, &v);
  return v;
}
static inline void reg_set(core_t *s, int64_t id, uint32_t v) { ((reg_rw_t)s->reg_write)(s->uc, (int)id, &v); }

#define SP rid[0]
#define LR rid[1]
#define PC rid[2]
#define XPSR rid[3]
#define PRIMASK rid[4]

EXPORT void core_request_stop(core_t *s) {
  if (s->limit > s->n + 1) s->limit = s->n + 1;
}

static inline int any_pending(core_t *s) { return (s->pending[0] | s->pending[1] | s->pending[2] | s->pending[3]) != 0; }
static inline void pend(core_t *s, int e) { s->pending[e >> 6] |= 1ull << (e & 63); }
static inline void unpend(core_t *s, int e) { s->pending[e >> 6] &= ~(1ull << (e & 63)); }

static inline int group(core_t *s, int p) { return s->prigroup >= 4 ? p >> (s->prigroup + 1) : p >> 4; }

EXPORT int64_t core_next_exception(core_t *s, int64_t primask) {
  int best = -1;
  if ((primask & 1) || !any_pending(s)) return -1;
  for (int w = 0; w < 4; w++) {
    uint64_t bits = s->pending[w];
    while (bits) {
      int e = w * 64 + __builtin_ctzll(bits);
      bits &= bits - 1;
      if (e >= IRQ_BASE && !(s->enabled[(e - IRQ_BASE) >> 6] >> ((e - IRQ_BASE) & 63) & 1)) continue;
      if (best < 0 || s->prio[e] < s->prio[best]) best = e; /* ascending e: ties keep the lower number */
    }
  }
  if (best < 0) return -1;
  if (s->n_active) {
    int current = 1 << 30;
    for (int i = 0; i < s->n_active; i++) {
      int g = group(s, s->prio[s->active[i]]);
      if (g < current) current = g;
    }
    if (group(s, s->prio[best]) >= current) return -1;
  }
  return best;
}

static int64_t earliest(core_t *s) {
  int64_t t[5] = {s->systick_next, s->tim[0].next, s->tim[1].next, s->shift_done, s->rx_done};
  int64_t m = NONE;
  for (int i = 0; i < 5; i++)
    if (t[i] != NONE && (m == NONE || t[i] < m)) m = t[i];
  return m;
}

/* the counter's limit that stops the slice at instruction count t (not before the next instruction) */
static uint64_t limit_at(core_t *s, int64_t t) {
  int64_t lim = t - s->slice_start - s->skip_base + 1;
  return lim < (int64_t)s->n + 1 ? s->n + 1 : (uint64_t)lim;
}

EXPORT void core_reschedule(core_t *s) {
  int64_t t = earliest(s);
  if (t != NONE && t < s->next_event) {
    uint64_t lim = limit_at(s, t);
    s->next_event = t;
    if (lim < s->limit) s->limit = lim;
  }
}

EXPORT void core_irq_check(core_t *s) {
  if (any_pending(s)) core_request_stop(s);
}

/* ---- USART1 ------------------------------------------------------------------------------------------------ */

static int64_t byte_cycles(core_t *s) {
  uint32_t brr = s->uregs[0x08 >> 2];
  return 10 * (int64_t)(brr ? brr : 729);
}

static uint32_t usart_sr(core_t *s) {
  uint32_t sr = s->uregs[0] & ~(uint32_t)(SR_TXE | SR_TC | SR_RXNE | SR_ORE);
  if (s->dr_full == NONE) {
    sr |= SR_TXE;
    if (s->shift_done == NONE && s->tc) sr |= SR_TC;
  }
  if (s->rx_dr != NONE) sr |= SR_RXNE;
  if (s->rx_ore) sr |= SR_ORE;
  return sr;
}

static void usart_irq_line(core_t *s) {
  uint32_t cr1 = s->uregs[0x0C >> 2], sr = usart_sr(s);
  if (((cr1 & CR1_TXEIE) && (sr & SR_TXE)) || ((cr1 & CR1_TCIE) && (sr & SR_TC)) ||
      ((cr1 & CR1_RXNEIE) && (sr & (SR_RXNE | SR_ORE))))
    pend(s, IRQ_USART1 + IRQ_BASE);
  else
    unpend(s, IRQ_USART1 + IRQ_BASE);
}

static void usart_start(core_t *s, int64_t byte) {
  s->shift_byte = byte;
  s->shift_done = s->now + byte_cycles(s);
  core_reschedule(s);
}

EXPORT uint32_t usart_read(core_t *s, uint32_t off) {
  if (off == 0x00) {
    uint32_t sr = usart_sr(s);
    s->ore_sr_read = s->rx_ore;
    return sr;
  }
  if (off == 0x04) {
    int64_t v = s->rx_dr != NONE ? s->rx_dr : s->rx_last;
    if (s->rx_dr != NONE) s->rx_last = s->rx_dr;
    s->rx_dr = NONE;
    if (s->ore_sr_read) {
      s->rx_ore = 0;
      s->ore_sr_read = 0;
    }
    usart_irq_line(s);
    return (uint32_t)v;
  }
  return s->uregs[(off >> 2) & 255];
}

EXPORT void usart_write(core_t *s, uint32_t off, uint32_t value) {
  touched(s);
  if (off == 0x04) {
    value &= 0xFF;
    s->tc = 0;
    if (s->shift_done == NONE)
      usart_start(s, value);
    else
      s->dr_full = value;
    usart_irq_line(s);
    return;
  }
  if (off == 0x00) {
    if (!(value & SR_TC)) s->tc = 0;
    if (!(value & SR_RXNE)) s->rx_dr = NONE;
    usart_irq_line(s);
    return;
  }
  s->uregs[(off >> 2) & 255] = value;
  if (off == 0x0C) usart_irq_line(s);
}

static void uart_out(core_t *s, int64_t byte, int64_t t) {
  if (s->out_len >= s->out_cap) ((py_event_t)s->py_event)(EV_OUT_FULL, 0);
  if (s->out_len < s->out_cap) {
    s->out_b[s->out_len] = (uint8_t)byte;
    s->out_t[s->out_len++] = t;
  }
}

EXPORT void shift_complete(core_t *s) {
  touched(s);
  uart_out(s, s->shift_byte, s->shift_done);
  s->shift_done = NONE;
  if (s->dr_full != NONE) {
    int64_t b = s->dr_full;
    s->dr_full = NONE;
    usart_start(s, b);
  } else {
    s->tc = 1;
  }
  usart_irq_line(s);
}

static void rx_schedule(core_t *s) {
  if (!s->rx_len) {
    s->rx_done = NONE;
    return;
  }
  int64_t head = s->rx_t[s->rx_head];
  s->rx_done = (head > s->rx_line_free ? head : s->rx_line_free) + byte_cycles(s);
  core_reschedule(s);
}

/* Queue n bytes starting at t (the caller made t >= now); keeps the queue by start time, stable. 0: full. */
EXPORT int64_t usart_inject(core_t *s, const uint8_t *data, int64_t n, int64_t t) {
  if (s->rx_len + n > s->rx_cap) return 0;
  for (int64_t k = 0; k < n; k++) {
    int64_t i = s->rx_len++; /* insertion: move later-starting bytes one up */
    while (i > 0 && s->rx_t[(s->rx_head + i - 1) % s->rx_cap] > t) {
      int64_t a = (s->rx_head + i) % s->rx_cap, b = (s->rx_head + i - 1) % s->rx_cap;
      s->rx_t[a] = s->rx_t[b];
      s->rx_b[a] = s->rx_b[b];
      i--;
    }
    s->rx_t[(s->rx_head + i) % s->rx_cap] = t;
    s->rx_b[(s->rx_head + i) % s->rx_cap] = data[k];
  }
  rx_schedule(s);
  return 1;
}

EXPORT void rx_complete(core_t *s) {
  touched(s);
  int64_t t = s->rx_done;
  uint8_t byte = s->rx_b[s->rx_head];
  s->rx_head = (s->rx_head + 1) % s->rx_cap;
  s->rx_len--;
  s->rx_line_free = t;
  if (s->rxlog_len < s->rxlog_cap) {
    s->rxlog_b[s->rxlog_len] = byte;
    s->rxlog_t[s->rxlog_len++] = t;
  }
  uint32_t cr1 = s->uregs[0x0C >> 2];
  if (!((cr1 & CR1_UE) && (cr1 & CR1_RE)))
    s->rx_lost++;
  else if (s->rx_dr != NONE) {
    s->rx_ore = 1;
    s->rx_overruns++;
  } else {
    s->rx_dr = byte;
    s->rx_received++;
  }
  rx_schedule(s);
  usart_irq_line(s);
}

/* MMIO callbacks of the USART1 page (uc_mmio_map) */
/* A USART1 SR read in thread mode. When the one before it was at the same instruction, read the same value, and
 * nothing in between could change what the CPU sees (no event, exception, other MMIO or Python call: the epoch;
 * the same core registers and the same stack top), the loop between the two reads (L instructions) repeats
 * unchanged until the next event: the clock moves over as many whole passes as fit before the slice ends. They
 * count as executed instructions; the firmware sees every register, every byte at the same instruction counts. */
static void poll_check(core_t *s, uint32_t sr) {
  if (!s->poll_skip || s->n_active) {
    s->poll_pc = -1;
    return;
  }
  uint32_t regs[16];
  void *ptrs[16];
  for (int i = 0; i < 16; i++) ptrs[i] = &regs[i];
  ((reg_batch_t)s->reg_read_batch)(s->uc, s->poll_ids, ptrs, 16);
  s->last_pc = reg_get(s, s->PC); /* (synced before each instruction's hook: the SR read's own address) */
  int64_t sp_off = (int64_t)regs[13] - RAM_BASE, len = 0;
  if (sp_off >= 0 && sp_off < (int64_t)RAM_SIZE) len = (int64_t)RAM_SIZE - sp_off < POLL_STACK ? (int64_t)RAM_SIZE - sp_off : POLL_STACK;
  if (s->poll_pc == s->last_pc && s->poll_epoch == s->io_epoch && s->poll_sr == (int64_t)sr &&
      s->poll_stack_len == len && !memcmp(regs, s->poll_regs, sizeof regs) &&
      (!len || !memcmp(s->ram + sp_off, s->poll_stack, (size_t)len))) {
    int64_t period = s->now - s->poll_now;
    int64_t k = period > 0 ? ((int64_t)s->limit - 1 - (int64_t)s->n) / period : 0;
    if (k > 0) {
      s->skip_base += k * period;
      s->limit -= (uint64_t)(k * period);
      s->instructions += k * period;
      s->polled += k * period;
      sync_now(s);
    }
  } else {
    memcpy(s->poll_regs, regs, sizeof regs);
    s->poll_stack_len = len;
    if (len) memcpy(s->poll_stack, s->ram + sp_off, (size_t)len);
    s->poll_pc = s->last_pc;
    s->poll_sr = sr;
    s->poll_epoch = s->io_epoch;
  }
  s->poll_now = s->now;
}

EXPORT uint64_t usart_mmio_read(void *uc, uint64_t off, unsigned size, void *user) {
  core_t *s = (core_t *)user;
  (void)uc;
  sync_now(s);
  if ((off & ~3u) == 0x00)
    poll_check(s, usart_sr(s));
  else
    touched(s);
  return lanes(usart_read(s, (uint32_t)off & ~3u), off, size);
}

EXPORT void usart_mmio_write(void *uc, uint64_t off, unsigned size, uint64_t value, void *user) {
  core_t *s = (core_t *)user;
  (void)uc;
  sync_now(s);
  uint32_t o = (uint32_t)off & ~3u;
  usart_write(s, o, merged(o == 0x04 ? 0 : s->uregs[(o >> 2) & 255], off, size, value)); /* DR is never stored */
}

enum { ADC_CR2 = 0x08, ADC_DR = 0x4C, ADC_EOC = 0x02, ADC_STRT = 0x10 }; /* ADC1: registers, SR bits */
#define ADC_SWSTART 0x40000000u

/* MMIO callbacks of a mirrored page (user: its mirror_t); ADC1's conversions (memory_map.Adc) run here */
EXPORT uint64_t mirror_mmio_read(void *uc, uint64_t off, unsigned size, void *user) {
  mirror_t *m = (mirror_t *)user;
  core_t *s = (core_t *)m->core;
  (void)uc;
  touched(s);
  uint64_t w = off >> 2;
  if (m->page == s->adc_page && w == ADC_DR / 4) { /* a conversion's reading; clears EOC */
    m->vals[0] &= ~ADC_EOC;
    return lanes((uint32_t)s->adc_dr, off, size);
  }
  if (w < 256 && m->served[w]) return lanes(m->vals[w], off, size);
  if (m->page == s->scs_page && w == 0x1004 / 4 && s->cyccnt_on) { /* DWT CYCCNT: the instruction clock */
    sync_now(s);
    return lanes((uint32_t)(s->now - s->cyccnt_base), off, size);
  }
  return ask_python(s, EV_MMIO, m->page, off, size, 0, 0);
}

EXPORT void mirror_mmio_write(void *uc, uint64_t off, unsigned size, uint64_t value, void *user) {
  mirror_t *m = (mirror_t *)user;
  core_t *s = (core_t *)m->core;
  (void)uc;
  touched(s);
  sync_now(s);
  uint32_t v = (uint32_t)value;
  if (m->page == s->adc_page && size == 4 && off == ADC_CR2) { /* SWSTART: a conversion, done at once */
    if (v & ADC_SWSTART) m->vals[0] |= ADC_EOC | ADC_STRT;
    m->vals[ADC_CR2 / 4] = v & ~ADC_SWSTART;
    return;
  }
  if (m->page == s->adc_page && size == 4 && off == 0) { /* SR: rc_w0 */
    m->vals[0] &= v;
    return;
  }
  ask_python(s, EV_MMIO, m->page, off, size, 1, value);
}

/* The peripheral bit-band alias: accesses to USART1's bits run here (as board/core.py's _bb_read/_bb_write on
 * the USART1 model), the others in Python. */
static int bb_usart(core_t *s, uint64_t off, uint32_t *reg, uint32_t *bit) {
  uint64_t addr = 0x40000000ull + (off >> 5);
  *bit = (uint32_t)(((off >> 2) & 7) | ((addr & 3) << 3));
  addr &= ~3ull;
  if (addr < (uint64_t)s->usart_base || addr >= (uint64_t)s->usart_base + 0x400) return 0;
  *reg = (uint32_t)(addr - (uint64_t)s->usart_base);
  return 1;
}

EXPORT uint64_t bb_mmio_read(void *uc, uint64_t off, unsigned size, void *user) {
  core_t *s = (core_t *)user;
  uint32_t reg, bit;
  (void)uc;
  touched(s);
  if (!bb_usart(s, off, &reg, &bit)) return ask_python(s, EV_BITBAND, 0, off, size, 0, 0);
  sync_now(s);
  return (usart_read(s, reg) >> bit) & 1;
}

EXPORT void bb_mmio_write(void *uc, uint64_t off, unsigned size, uint64_t value, void *user) {
  core_t *s = (core_t *)user;
  uint32_t reg, bit;
  (void)uc;
  touched(s);
  if (!bb_usart(s, off, &reg, &bit)) {
    ask_python(s, EV_BITBAND, 0, off, size, 1, value);
    return;
  }
  sync_now(s);
  uint32_t old = reg == 0 ? s->uregs[0] : usart_read(s, reg);
  usart_write(s, reg, (value & 1) ? (old | (1u << bit)) : (old & ~(1u << bit)));
}

/* ---- timers ------------------------------------------------------------------------------------------------ */

#define TIM_CR1 0x00
#define TIM_DIER 0x0C
#define TIM_SR 0x10
#define TIM_EGR 0x14
#define TIM_CNT 0x24
#define TIM_PSC 0x28
#define TIM_ARR 0x2C

static inline int64_t timer_period(ctimer_t *t) {
  return ((int64_t)t->regs[TIM_PSC >> 2] + 1) * ((int64_t)t->regs[TIM_ARR >> 2] + 1);
}

static void timer_irq_line(core_t *s, ctimer_t *t) {
  if (t->irq >= 0 && (t->regs[TIM_SR >> 2] & t->regs[TIM_DIER >> 2] & 0xFF)) pend(s, (int)t->irq + IRQ_BASE);
}

EXPORT uint32_t timer_read(core_t *s, int64_t i, uint32_t off) {
  ctimer_t *t = &s->tim[i];
  if (off == TIM_CNT && t->next != NONE) {
    int64_t psc = (int64_t)t->regs[TIM_PSC >> 2] + 1;
    int64_t v = timer_period(t) - (t->next - s->now);
    return (uint32_t)(v >= 0 ? v / psc : -((-v + psc - 1) / psc)); /* Python's floor division */
  }
  return t->regs[(off >> 2) & 255];
}

EXPORT void timer_write(core_t *s, int64_t i, uint32_t off, uint32_t value) {
  ctimer_t *t = &s->tim[i];
  if (off == TIM_SR) { /* rc_w0 */
    t->regs[TIM_SR >> 2] &= value;
    timer_irq_line(s, t);
    return;
  }
  t->regs[(off >> 2) & 255] = value;
  if (off == TIM_CR1) {
    int running = (value & 1) && t->regs[TIM_ARR >> 2] > 0;
    if (running && t->next == NONE) {
      t->next = s->now + timer_period(t);
      core_reschedule(s);
    } else if (!running) {
      t->next = NONE;
    }
  } else if (off == TIM_DIER) {
    timer_irq_line(s, t);
  } else if (off == TIM_EGR && (value & 1)) { /* UG: update flag unless URS */
    if (!(t->regs[TIM_CR1 >> 2] & 4)) {
      t->regs[TIM_SR >> 2] |= 1;
      timer_irq_line(s, t);
    }
  }
}

static void timer_update(core_t *s, int64_t i) {
  touched(s);
  ctimer_t *t = &s->tim[i];
  int64_t period = timer_period(t);
  t->updates++;
  if (t->first_update == NONE) t->first_update = s->now;
  t->next = (t->next ? t->next : s->now) + (period > 1 ? period : 1);
  t->regs[TIM_SR >> 2] |= 1;
  timer_irq_line(s, t);
  if (i != 0) return;
  int64_t j = t->updates - s->plan_u0;
  if (j < 0 || j >= s->plan_n || s->now >= s->plan_until) {
    ((py_event_t)s->py_event)(EV_TICK, 0);
    return;
  }
  memcpy(s->sensor_img[0] + 0x22, s->plan_img + 12 * j, 12);
  s->sensor_img[0][0x1E] = 0x07; /* STATUS_REG: data ready */
  s->sensor_valid = t->updates;
  if (s->plan_len) memcpy(s->ram + (s->plan_addr - RAM_BASE), s->plan_ram + s->plan_len * j, (size_t)s->plan_len);
}

EXPORT uint64_t timer_mmio_read(void *uc, uint64_t off, unsigned size, void *user) {
  ctimer_t *t = (ctimer_t *)user;
  core_t *s = (core_t *)t->core;
  (void)uc;
  sync_now(s);
  touched(s);
  return lanes(timer_read(s, t - s->tim, (uint32_t)off & ~3u), off, size);
}

EXPORT void timer_mmio_write(void *uc, uint64_t off, unsigned size, uint64_t value, void *user) {
  ctimer_t *t = (ctimer_t *)user;
  core_t *s = (core_t *)t->core;
  (void)uc;
  sync_now(s);
  touched(s);
  uint32_t o = (uint32_t)off & ~3u;
  timer_write(s, t - s->tim, o, merged(t->regs[(o >> 2) & 255], off, size, value));
}

/* ---- exceptions -------------------------------------------------------------------------------------------- */

static void take(core_t *s, int exc) {
  touched(s);
  uint32_t vals[26];
  uint64_t d[8]; /* s0-s15 as d0-d7: half the register reads */
  void *ptrs[FRAME_READS];
  for (int i = 0; i < 8; i++) ptrs[i] = &vals[i];
  for (int k = 0; k < 8; k++) ptrs[8 + k] = &d[k];
  ptrs[16] = &vals[24]; /* fpscr */
  ((reg_batch_t)s->reg_read_batch)(s->uc, s->frame_ids, ptrs, FRAME_READS);
  memcpy(vals + 8, d, sizeof d);
  uint32_t sp = reg_get(s, s->SP), xpsr = vals[7], align = sp & 4;
  sp -= align + FP_FRAME_WORDS * 4;
  vals[7] = (xpsr & ~(1u << 9)) | (align ? (1u << 9) : 0);
  int64_t off = (int64_t)sp - RAM_BASE;
  if (off < 0 || off > (int64_t)RAM_SIZE - FP_FRAME_WORDS * 4) {
    s->fault = F_STACK;
    s->fault_arg = ((int64_t)exc << 32) | sp;
    core_request_stop(s);
    return;
  }
  vals[25] = 0;
  memcpy(s->ram + off, vals, 104);
  int handler_mode = s->n_active > 0;
  if (!handler_mode) s->exc_started = instructions_now(s);
  reg_set(s, s->SP, sp);
  reg_set(s, s->LR, handler_mode ? 0xFFFFFFE1u : 0xFFFFFFE9u);
  reg_set(s, s->XPSR, (xpsr & 0xF8000000u) | (1u << 24) | (uint32_t)exc);
  uint32_t vector;
  memcpy(&vector, s->flash + ((s->vtor + 4 * exc) & (FLASH_SIZE - 1)), 4);
  unpend(s, exc);
  if (s->n_active < 64) s->active[s->n_active++] = exc;
  s->counts[exc & 255]++;
  reg_set(s, s->PC, vector | 1);
}

static void leave(core_t *s) {
  touched(s);
  uint32_t exc_return = reg_get(s, s->PC) | 0xF0000000u;
  if (!s->n_active) {
    s->fault = F_RETURN;
    core_request_stop(s);
    return;
  }
  s->n_active--;
  if (!s->n_active) s->exc_instructions += instructions_now(s) - s->exc_started;
  uint32_t sp = reg_get(s, s->SP);
  int extended = !(exc_return & 0x10);
  int words = extended ? FP_FRAME_WORDS : 8;
  int64_t off = (int64_t)sp - RAM_BASE;
  if (off < 0 || off > (int64_t)RAM_SIZE - words * 4) {
    s->fault = F_RETURN;
    core_request_stop(s);
    return;
  }
  uint32_t raw[26];
  memcpy(raw, s->ram + off, 4 * words);
  sp += 4 * words;
  uint32_t xpsr = raw[7];
  if (xpsr & (1u << 9)) sp += 4;
  /* the level-triggered lines again: USART1, TIM9 */
  usart_irq_line(s);
  timer_irq_line(s, &s->tim[0]);
  uint64_t d[8];
  void *ptrs[FRAME_WRITES];
  for (int i = 0; i < 6; i++) ptrs[i] = &raw[i];
  memcpy(d, raw + 8, sizeof d);
  for (int k = 0; k < 8; k++) ptrs[6 + k] = &d[k];
  ptrs[14] = &raw[24];
  ((reg_batch_t)s->reg_write_batch)(s->uc, s->wframe_ids, ptrs, extended ? FRAME_WRITES : 6);
  reg_set(s, s->SP, sp);
  reg_set(s, s->XPSR, xpsr & ~(1u << 9));
  reg_set(s, s->PC, raw[6] | 1);
  if (any_pending(s)) {
    int64_t nxt = core_next_exception(s, reg_get(s, s->PRIMASK));
    if (nxt >= 0) take(s, (int)nxt);
  }
}

EXPORT void core_intr_hook(void *uc, uint32_t intno, void *user) {
  core_t *s = (core_t *)user;
  (void)uc;
  if (intno != 8) {
    sync_now(s);
    if (!s->fault) {
      s->fault = F_CPU_EXC;
      s->fault_arg = intno;
    }
    core_request_stop(s);
    return;
  }
  leave(s);
}

/* ---- events ------------------------------------------------------------------------------------------------ */

static void systick_fire(core_t *s) {
  touched(s);
  s->countflag = 1;
  s->systick_next = (s->systick_next ? s->systick_next : s->now) + s->systick_period;
  if (s->systick_tickint) pend(s, EXC_SYSTICK);
}

static void fire_events(core_t *s) {
  int64_t now = s->now;
  for (int round = 0; round < 64; round++) {
    int fired = 0;
    if (s->shift_done != NONE && s->shift_done <= now) {
      shift_complete(s);
      fired = 1;
    }
    if (s->rx_done != NONE && s->rx_done <= now) {
      rx_complete(s);
      fired = 1;
    }
    if (s->systick_next != NONE && s->systick_next <= now) {
      systick_fire(s);
      fired = 1;
    }
    for (int i = 0; i < 2; i++) {
      if (s->tim[i].next != NONE && s->tim[i].next <= now) {
        timer_update(s, i);
        fired = 1;
      }
    }
    if (!fired) return;
  }
}

/* ---- hooks ------------------------------------------------------------------------------------------------- */

/* The CPU (thread mode) has nothing to do until the next event: jump there, fire it, take its interrupt in the
 * hook; the polled instruction runs again after the handler, normally. */
static void skip_to_event(core_t *s) {
  if (s->n_active) return;
  if (s->resumed_idle) {
    s->resumed_idle = 0;
    return;
  }
  int64_t now = s->slice_start + (int64_t)s->n + s->skip_base;
  int64_t nxt = earliest(s);
  if (nxt == NONE || nxt >= s->run_end) {
    if (s->run_end > now) {
      s->skipped += s->run_end - now;
      s->skip_base += s->run_end - now;
    }
    s->limit = s->n + 1;
    return;
  }
  if (nxt > now) {
    s->skipped += nxt - now;
    s->skip_base += nxt - now;
  }
  sync_now(s);
  fire_events(s);
  if (any_pending(s)) {
    int64_t exc = core_next_exception(s, reg_get(s, s->PRIMASK));
    if (exc >= 0) {
      s->n -= 1;
      s->skip_base += 1;
      s->resumed_idle = 1;
      take(s, (int)exc);
    }
  }
  int64_t end = earliest(s);
  end = (end == NONE || end > s->run_end) ? s->run_end : end;
  s->next_event = end;
  s->limit = limit_at(s, end);
}

static void idle_hook(core_t *s, uint64_t address) {
  for (int k = 0; k < s->n_idle; k++) {
    if ((uint64_t)s->idle_addr[k] != address) continue;
    if (any_pending(s)) return;
    for (int j = 0; j < s->idle_n_words[k]; j++) {
      uint32_t v = 0;
      memcpy(&v, s->ram + s->idle_off[k][j], (size_t)s->idle_size[k][j]);
      if (v) return;
    }
    if (s->idle_lo[k] != s->idle_hi[k]) {
      int64_t lr = reg_get(s, s->LR) & ~1u;
      if (!(s->idle_lo[k] <= lr && lr < s->idle_hi[k])) return;
    }
    skip_to_event(s);
    return;
  }
}

/* wfi in thread mode with no interrupt to take (PRIMASK aside): sleep to the next event (core.py's _on_wfi) */
static void wfi_hook(core_t *s) {
  if (!s->n_active && core_next_exception(s, 0) < 0) skip_to_event(s);
}

/* Sensor_IO_Read(handle, reg, buf, n) from the register images; Python when the image is not current */
static void sensor_read_hook(core_t *s) {
  uint32_t handle = reg_get(s, s->rid[5]), reg = reg_get(s, s->rid[6]) & 0x7F, buf = reg_get(s, s->rid[7]);
  uint32_t n = reg_get(s, s->rid[8]) & 0xFFFF;
  int64_t dev = -1;
  if (handle + 3 >= RAM_BASE && handle + 3 < RAM_BASE + RAM_SIZE) dev = s->ram[handle + 3 - RAM_BASE];
  int ok = dev >= 0 && dev < 3 && s->sensor_fast[dev] && buf >= RAM_BASE && buf + n <= RAM_BASE + RAM_SIZE;
  if (ok && dev == 0) ok = s->tim[0].updates > 0 && s->sensor_valid == s->tim[0].updates;
  if (!ok) {
    sync_now(s);
    ((py_event_t)s->py_event)(EV_SENSOR, 0);
    return;
  }
  for (uint32_t i = 0; i < n; i++) s->ram[buf - RAM_BASE + i] = s->sensor_img[dev][(reg + i) & 0x7F];
  s->sensor_reads++;
  reg_set(s, s->rid[5], 0);
  reg_set(s, s->PC, reg_get(s, s->LR) | 1);
}

/* ---- the code sites: one unicorn code hook (the counter) dispatches them all ---------------------------------- */

/* Add a site (kind, arg) at addr, after those already there. 0: no room or not in flash. */
EXPORT int64_t core_add_site(core_t *s, int64_t addr, int64_t kind, int64_t arg) {
  uint64_t off = (uint64_t)addr - FLASH_BASE;
  if (s->n_sites >= MAX_SITES || off >= FLASH_SIZE) return 0;
  int64_t i = s->n_sites++;
  while (i > 0 && s->site_addr[i - 1] > addr) {
    s->site_addr[i] = s->site_addr[i - 1];
    s->site_kind[i] = s->site_kind[i - 1];
    s->site_arg[i] = s->site_arg[i - 1];
    i--;
  }
  s->site_addr[i] = addr;
  s->site_kind[i] = kind;
  s->site_arg[i] = arg;
  s->site_map[off >> 4] |= (uint8_t)(1u << ((off >> 1) & 7));
  return 1;
}

/* A mark: the clock, the counters and the marked RAM bytes, as a Python probe here would read them. */
static void mark(core_t *s, int64_t kind) {
  if (s->mark_len >= s->mark_cap) ((py_event_t)s->py_event)(EV_MARKS_FULL, 0);
  if (s->mark_len >= s->mark_cap) return; /* (Python could not take them: it stopped the run) */
  sync_now(s);
  int64_t *w = s->mark_w + MARK_WORDS * s->mark_len;
  w[0] = kind;
  w[1] = s->now;
  w[2] = instructions_now(s);
  w[3] = s->exc_instructions;
  w[4] = s->cyccnt_on ? s->now - s->cyccnt_base : s->cyccnt_frozen;
  w[5] = s->tim[0].updates;
  uint8_t *b = s->mark_b + s->mark_bytes * s->mark_len;
  for (int64_t k = 0; k < s->n_mark_ranges; k++) {
    memcpy(b, s->ram + s->mark_off[k], (size_t)s->mark_size[k]);
    b += s->mark_size[k];
  }
  s->mark_len++;
}

/* Out of line: the count hook's common path (no site here) then saves no registers. */
COLD static void dispatch(core_t *s, uint64_t address, uint32_t size) {
  touched(s);
  int64_t lo = 0, hi = s->n_sites;
  while (lo < hi) {
    int64_t mid = (lo + hi) / 2;
    if ((uint64_t)s->site_addr[mid] < address)
      lo = mid + 1;
    else
      hi = mid;
  }
  for (int64_t i = lo; i < s->n_sites && (uint64_t)s->site_addr[i] == address; i++) {
    switch (s->site_kind[i]) {
      case K_UNMASK: core_irq_check(s); break; /* after cpsie i / msr primask: take what became pending */
      case K_IDLE: idle_hook(s, address); break;
      case K_WFI: wfi_hook(s); break;
      case K_SENSOR: sensor_read_hook(s); break;
      case K_MARK: mark(s, s->site_arg[i]); break;
      case K_PY:
        s->hook_addr = (int64_t)address;
        s->hook_size = size;
        ((py_event_t)s->py_event)(EV_CODE, s->site_arg[i]);
        break;
    }
  }
}

/* before every instruction (UC_HOOK_CODE over all addresses): count, stop at the limit, run the sites here */
EXPORT void core_count_hook(void *uc, uint64_t address, uint32_t size, void *user) {
  core_t *s = (core_t *)user;
  if (++s->n >= s->limit) {
    ((emu_stop_t)s->emu_stop)(uc);
    return;
  }
  uint64_t off = address - FLASH_BASE;
  if (off < FLASH_SIZE && (s->site_map[off >> 4] >> ((off >> 1) & 7) & 1)) dispatch(s, address, size);
}

/* unicorn's virtual TLB (UC_TLB_VIRTUAL): addresses map to themselves; RAM is not executable unless fetched from
 * (unicorn keeps stores to an executable page on its slow path). uc_tlb_entry: paddr, perms. */
typedef struct {
  uint64_t paddr;
  int32_t perms;
} tlb_entry_t;

EXPORT int core_tlb_fill(void *uc, uint64_t addr, int type, tlb_entry_t *e, void *user) {
  (void)uc;
  (void)user;
  e->paddr = addr;
  e->perms = (addr >= RAM_BASE && addr < RAM_BASE + RAM_SIZE && type != 18) ? 3 : 7; /* 18: UC_MEM_FETCH */
  return 1;
}

/* ---- the event loop ---------------------------------------------------------------------------------------- */

/* Run until the clock reaches t_end. 0: done; 1: a fault (s->fault says which). */
EXPORT int64_t core_run(core_t *s, int64_t t_end) {
  s->run_end = t_end;
  while (s->now < t_end) {
    if (s->fault) return 1;
    fire_events(s);
    if (s->fault) return 1;
    if (any_pending(s)) {
      int64_t nxt = core_next_exception(s, reg_get(s, s->PRIMASK));
      if (nxt >= 0) take(s, (int)nxt);
    }
    int64_t ev = earliest(s), end = t_end;
    if (s->now + s->max_slice < end) end = s->now + s->max_slice;
    if (ev != NONE && ev < end) end = ev;
    s->next_event = end;
    s->slice_start = s->now;
    s->skip_base = 0;
    s->n = 0;
    s->limit = (uint64_t)((end - s->now > 1 ? end - s->now : 1) + 1);
    uint32_t pc = reg_get(s, s->PC);
    s->slices++;
    int err = ((emu_start_t)s->emu_start)(s->uc, pc | 1, 0xFFFFFFFEull, 0, 0);
    if (err) {
      sync_now(s);
      if (!s->fault) {
        s->fault = F_EMU;
        s->fault_arg = err;
      }
      return 1;
    }
    int64_t executed = s->n >= s->limit ? (int64_t)s->n - 1 : (int64_t)s->n;
    s->instructions += executed;
    s->now = s->slice_start + executed + s->skip_base;
    s->n = 0;
    s->slice_start = s->now;
    s->skip_base = 0;
    if (s->fault) return 1;
  }
  return 0;
}

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_core",
                                    "The emulated board's hot path in C (board.native)", -1, NULL};

PyMODINIT_FUNC PyInit__core(void) { return PyModule_Create(&moddef); }

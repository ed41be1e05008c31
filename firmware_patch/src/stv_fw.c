/* steval-link firmware port for the STM32F401 (see stv_fw.h). */
#include "stv_fw.h"

/* Cortex-M4 core debug: DEMCR.TRCENA enables the DWT; DWT_CTRL.CYCCNTENA starts CYCCNT. */
#define STV_DEMCR (*(volatile uint32_t *)0xE000EDFCu)
#define STV_DEMCR_TRCENA (1u << 24)
#define STV_DWT_CTRL (*(volatile uint32_t *)0xE0001000u)
#define STV_DWT_CYCCNT (*(volatile uint32_t *)0xE0001004u)

/* USART1 (APB2, 0x40011000): SR, DR, CR1. */
#define STV_USART1_BASE 0x40011000u
#define STV_USART1_SR (*(volatile uint32_t *)(STV_USART1_BASE + 0x00u))
#define STV_USART1_DR (*(volatile uint32_t *)(STV_USART1_BASE + 0x04u))
#define STV_USART1_CR1 (*(volatile uint32_t *)(STV_USART1_BASE + 0x0Cu))
#define STV_USART_SR_TXE (1u << 7)
#define STV_USART_SR_RXNE (1u << 5)
#define STV_USART_CR1_TXEIE_BIT 7u
#define STV_USART_CR1_RXNEIE_BIT 5u
/* CR1.TXEIE through the peripheral bit-band alias: set/cleared atomically by main loop and ISR alike. */
#define STV_USART1_TXEIE_BB \
  (*(volatile uint32_t *)(0x42000000u + ((STV_USART1_BASE + 0x0Cu - 0x40000000u) * 32u) + STV_USART_CR1_TXEIE_BIT * 4u))

/* CR1.RXNEIE through the bit-band alias (the TX side sets/clears TXEIE the same way). */
#define STV_USART1_RXNEIE_BB \
  (*(volatile uint32_t *)(0x42000000u + ((STV_USART1_BASE + 0x0Cu - 0x40000000u) * 32u) + STV_USART_CR1_RXNEIE_BIT * 4u))

/* ST's firmware: the throttle, the arming flag and the filter state of ahrs.c. */
extern int16_t gTHR;
extern int32_t rc_enable_motor;
extern float q0, q1, q2, q3, exInt, eyInt, ezInt;

static stv_link_t g_stv;
static stv_cmd_t g_cmd;
static volatile uint8_t g_stv_ready;

/* The build's values until stv_fw_init copies the configuration's (ahrs.h's constants) and a command changes them. */
stv_filter_t stv_filter = {10.0f, 0.4f, AHRS_KI, 200, AHRS_NO_CORRECTION ? 0u : 1u};

static inline uint32_t irq_save(void) {
  uint32_t primask;
  __asm__ volatile("mrs %0, primask\n\tcpsid i" : "=r"(primask)::"memory");
  return primask;
}

static inline void irq_restore(uint32_t primask) { __asm__ volatile("msr primask, %0" ::"r"(primask) : "memory"); }

static inline void tx_kick(void) {
  if (stv_txq_used(&g_stv.txq)) STV_USART1_TXEIE_BB = 1u;
}

void stv_fw_init(const stv_link_config_t *cfg) {
  STV_DEMCR |= STV_DEMCR_TRCENA;
  STV_DWT_CTRL |= 1u; /* CYCCNTENA; CYCCNT keeps counting from where it is */
  stv_link_init(&g_stv, cfg, STV_DWT_CYCCNT);
  stv_filter.kp_ground = cfg->kp_ground;
  stv_filter.kp_flight = cfg->kp_flight;
  stv_filter.ki = cfg->ki;
  stv_filter.min_thr = cfg->min_thr;
  stv_filter.correction = (cfg->flags & STV_FLAG_NO_CORRECTION) ? 0u : 1u;
  stv_rxq_init(&g_cmd.rx);
  stv_cmd_dec_init(&g_cmd.dec);
  g_cmd.filter = &stv_filter;
  g_cmd.q[0] = &q0;
  g_cmd.q[1] = &q1;
  g_cmd.q[2] = &q2;
  g_cmd.q[3] = &q3;
  g_cmd.ints[0] = &exInt;
  g_cmd.ints[1] = &eyInt;
  g_cmd.ints[2] = &ezInt;
  g_cmd.inflight_ok = STV_INFLIGHT_TUNING ? 1u : 0u;
  if (g_cmd.inflight_ok) g_stv.cfg.flags |= STV_FLAG_INFLIGHT_TUNING;
  g_stv_ready = 1u;
  (void)STV_USART1_SR; /* clear a stale overrun (SR then DR), then take RX interrupts */
  (void)STV_USART1_DR;
  STV_USART1_RXNEIE_BB = 1u;
}

void stv_fw_step_begin(int16_t thr) {
  uint32_t s = irq_save();
  stv_link_step_begin(&g_stv, STV_DWT_CYCCNT, thr);
  irq_restore(s);
  g_stv.cyc_begin = STV_DWT_CYCCNT; /* count from here: ahrs_fusion_ag + QuaternionToEuler, not our bookkeeping */
}

int16_t stv_thr_used;

void stv_fw_step_end(const float acc_mg[3], const float gyro_mdps[3], const float q[4], const float euler_rad[3]) {
  uint32_t cyc = STV_DWT_CYCCNT;
  uint32_t s = irq_save();
  int16_t thr = gTHR;
  uint8_t armed = rc_enable_motor != 0;
  stv_command_t cmd;
  g_stv.thr = stv_thr_used; /* what the filter used (see stv_fw.h) */
  g_stv.cfg.flags = (uint16_t)((g_stv.cfg.flags & ~STV_FLAG_ARMED) |
                               ((armed || thr >= stv_filter.min_thr) ? STV_FLAG_ARMED : 0u));
  stv_link_step_end(&g_stv, cyc, acc_mg, gyro_mdps, q, euler_rad);
  tx_kick();
  irq_restore(s);
  /* Between two AHRS steps: the commands received since the last step (nothing to do when none came). */
  while (stv_cmd_next(&g_cmd, &cmd)) {
    s = irq_save();
    stv_cmd_execute(&g_cmd, &g_stv, &cmd, gTHR, rc_enable_motor != 0);
    tx_kick();
    irq_restore(s);
  }
}

void stv_fw_log_write(const char *str, size_t n) {
  uint32_t s;
  if (!g_stv_ready) return;
  s = irq_save();
  stv_link_update_time(&g_stv, STV_DWT_CYCCNT);
  stv_link_log_write(&g_stv, str, n);
  tx_kick();
  irq_restore(s);
}

void stv_fw_usart1_irq(void) {
  uint32_t sr = STV_USART1_SR;
  if (sr & (STV_USART_SR_RXNE | 0x0Fu)) {
    /* a received byte (SR then DR also clears ORE/NE/FE/PE; a byte lost to an overrun fails its frame's CRC) */
    uint8_t b = (uint8_t)STV_USART1_DR;
    if (sr & STV_USART_SR_RXNE) (void)stv_rxq_push(&g_cmd.rx, b);
  }
  if ((sr & STV_USART_SR_TXE) && (STV_USART1_CR1 & (1u << STV_USART_CR1_TXEIE_BIT))) {
    uint8_t b;
    if (stv_txq_pop_byte(&g_stv.txq, &b))
      STV_USART1_DR = b;
    else
      STV_USART1_TXEIE_BB = 0u; /* queue empty: stop TXE interrupts until the next frame */
  }
}

uint32_t stv_fw_dropped(void) { return g_stv.txq.dropped; }

int stv_fw_flight_due(void) {
  return g_stv_ready && stv_link_flight_due(&g_stv);
}

void stv_fw_flight(const float euler_rc[3], int16_t ail, int16_t ele, int16_t rud, int16_t thr,
                   const volatile float *pid_s, const volatile float *motor_pwm, float vbat_v, uint16_t fc_flags) {
  stv_flight_t fc;
  uint32_t s;
  int i;
  for (i = 0; i < 3; i++) fc.euler_rc_rad[i] = euler_rc[i];
  fc.rc[0] = ail;
  fc.rc[1] = ele;
  fc.rc[2] = rud;
  fc.rc[3] = thr;
  fc.vbat_v = vbat_v;
  fc.fc_flags = fc_flags;
  s = irq_save();
  for (i = 0; i < 3; i++) {
    fc.outer_s1[i] = pid_s[2 * i];
    fc.inner_s2[i] = pid_s[2 * i + 1];
  }
  for (i = 0; i < 4; i++) fc.motor_pwm[i] = motor_pwm[i];
  stv_link_send_flight(&g_stv, &fc);
  tx_kick();
  irq_restore(s);
}

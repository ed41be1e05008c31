/* Reference firmware for the STEVAL-FCU001V1: the STEVAL loop in one file.
 *
 * TIM9 interrupt, 807.7 Hz: read the LSM6DSL, remove the offsets, low-pass the gyro, fill 5-sample FIFOs, run the
 * inner (rate) loop and drive the motors. Main loop, every 5th tick (161.5 Hz): average the FIFOs, run the Mahony
 * filter, send the step's frames (stv_fw), read the remote, run the outer (angle) loop. Power-up: 1 s for the
 * sensors to settle, then 800 ticks of offset calibration (keep the drone still): the first step comes at 2.985 s.
 * Test equipment and a teaching aid, not a flight firmware. */
#include <string.h>

#include "ref.h"
#include "regs.h"
#include "stv_fw.h"

/* the BLE remote (written by the radio on the drone, by the emulator here): joydata[2] rudder, [3] throttle,
 * [4] aileron, [5] elevator (128 = centred), [7] bit 2 armed; connected while a remote is connected */
volatile uint8_t joydata[8];
volatile int connected;

int16_t gAIL, gELE, gTHR, gRUD; /* sticks, +-1800 full scale; throttle 0..3315 */
int32_t rc_enable_motor;        /* armed */
int32_t rc_connection_flag;
float VBAT;                     /* battery, V */

axes_f acc_ahrs, gyro_ahrs; /* the filter's inputs (mg, mdps) */
quat_f ahrs;
euler_f euler_ahrs, euler_rc;

/* the ISR's state */
static int32_t acc_offset[3] = {0, 0, 1000}, gyro_offset[3];
static int32_t acc_sum[3], gyro_sum[3];
static int calibrated, cal_ticks, fifo_n;
static float gyro_x1[3], gyro_x2[3], gyro_y1[3], gyro_y2[3]; /* IIR memory */
static float acc_fifo[FIFO_ORDER][3], gyro_fifo[FIFO_ORDER][3];
static float acc_step[FIFO_ORDER][3], gyro_step[FIFO_ORDER][3]; /* the 5 samples handed to the main loop */
volatile uint32_t tim9_event_flag;

/* gyro IIR: 2nd-order Butterworth, 100 Hz at 800 Hz; y = b0 x + b1 x1 + b2 x2 + a1 y1 + a2 y2 */
static const float iir_a1 = 0.94280904158206336, iir_a2 = -0.33333333333333343;
static const float iir_b0 = 0.09763107293781749, iir_b1 = 0.19526214587563498, iir_b2 = 0.09763107293781749;

#if PRINTF_EVERY_LOOP
#include <stdio.h>

/* ST's unpatched loop: PRINTF is a blocking transmit. Each byte waits for TXE, the last for TC, polling the status
 * register with a timeout on the ms tick (as HAL_UART_Transmit does). Our own code, not ST's. */
#define UART_TIMEOUT_MS 100u

static int uart_wait(uint32_t flag, uint32_t t0) {
  while (!(USART1_SR & flag)) {
    if ((uint32_t)(uwTick - t0) > UART_TIMEOUT_MS) return -1;
  }
  return 0;
}

static void uart_transmit(const char *s, size_t n) {
  uint32_t t0 = uwTick;
  for (size_t i = 0; i < n; i++) {
    if (uart_wait(1u << 7, t0)) return; /* TXE */
    USART1_DR = (uint8_t)s[i];
  }
  (void)uart_wait(1u << 6, t0); /* TC */
}

static void log_line(const char *s) { uart_transmit(s, strlen(s)); }

/* One TSV line per pass, as ST's 221117 prints: with newlib-nano's printf (no _printf_float) the %f fields are
 * empty. */
static void print_loop_line(uint32_t pass) {
  char line[160];
  int n = snprintf(line, sizeof line, "%d\t%d\t%d\t%d\t%d\t%d\t%d\t%f\t%f\t%f\t%d\r\n", (int)pass,
                   (int)acc_ahrs.x, (int)acc_ahrs.y, (int)acc_ahrs.z, (int)gyro_ahrs.x, (int)gyro_ahrs.y,
                   (int)gyro_ahrs.z, (double)euler_ahrs.thx, (double)euler_ahrs.thy, (double)euler_ahrs.thz, (int)gTHR);
  if (n > 0) uart_transmit(line, strlen(line)); /* (n counts what nano's printf skipped) */
}
#else
static void log_line(const char *s) {
  if (LINK_OUTPUT) stv_fw_log_write(s, strlen(s));
}
#endif

void TIM1_BRK_TIM9_IRQHandler(void) {
  int32_t acc[3], gyro[3];
  float gyro_fil[3], gyro_rad[3];
  if (!(TIM_SR(TIM9) & 1u)) return; /* no update pending: a late repeat of the last one */
  TIM_SR(TIM9) = ~1u;                /* clear UIF (the other flags are rc_w0: writing 1 keeps them) */
  if (!calibrated) { /* ticks 1..800 ignored, 801..1600 summed: offset = sum / 800 */
    if (++cal_ticks <= 800) return;
    imu_read(acc, gyro);
    for (int i = 0; i < 3; i++) {
      acc_sum[i] += acc[i];
      gyro_sum[i] += gyro[i];
    }
    if (cal_ticks < 1600) return;
    for (int i = 0; i < 3; i++) {
      acc_offset[i] = (int32_t)(acc_sum[i] * 0.00125f);
      gyro_offset[i] = (int32_t)(gyro_sum[i] * 0.00125f);
    }
    calibrated = 1; /* and this tick runs the pipeline too */
  }
  imu_read(acc, gyro);
  for (int i = 0; i < 3; i++) {
    acc[i] -= (i == 2) ? acc_offset[2] - 1000 : acc_offset[i]; /* z keeps the 1 g */
    gyro[i] -= gyro_offset[i];
    gyro_fil[i] = iir_b0 * gyro[i] + iir_b1 * gyro_x1[i] + iir_b2 * gyro_x2[i] + iir_a1 * gyro_y1[i] +
                  iir_a2 * gyro_y2[i];
    gyro_x2[i] = gyro_x1[i];
    gyro_x1[i] = gyro[i];
    gyro_y2[i] = gyro_y1[i];
    gyro_y1[i] = gyro_fil[i];
    acc_fifo[fifo_n][i] = acc[i];
    gyro_fifo[fifo_n][i] = gyro_fil[i];
    gyro_rad[i] = gyro_fil[i] * (float)COE_MDPS_TO_RADPS;
  }
  if (++fifo_n == FIFO_ORDER) { /* every 5th tick: hand the FIFOs to the main loop */
    fifo_n = 0;
    memcpy(acc_step, acc_fifo, sizeof acc_step);
    memcpy(gyro_step, gyro_fifo, sizeof gyro_step);
    tim9_event_flag = 1u;
  }
  euler_ahrs.thz += gyro_rad[2] * PID_SAMPLING_TIME; /* yaw: integrated gyro */
  if (gTHR < MIN_THR) euler_rc.thz = euler_ahrs.thz = 0.0f;
  if (rc_connection_flag && rc_enable_motor) FlightControlPID_innerLoop(gyro_rad);
  else set_motor_pwm_zero();
  if (gTHR < MIN_THR) set_motor_pwm_zero();
  set_motor_pwm();
}

void USART1_IRQHandler(void) { stv_fw_usart1_irq(); } /* TX queue out, command bytes in */

/* The FIFO average: float sum, then *= 1.0/5 in double (as ST's firmware). */
static void average(float fifo[FIFO_ORDER][3], axes_f *out) {
  out->x = out->y = out->z = 0.0f;
  for (int i = 0; i < FIFO_ORDER; i++) {
    out->x += fifo[i][0];
    out->y += fifo[i][1];
    out->z += fifo[i][2];
  }
  out->x *= (1.0 / FIFO_ORDER);
  out->y *= (1.0 / FIFO_ORDER);
  out->z *= (1.0 / FIFO_ORDER);
}

/* Sticks from the remote's bytes (ST's BLE app), once per step. */
static void read_remote(void) {
  gRUD = (int16_t)((joydata[2] - 128) * (-13));
  gTHR = (int16_t)(joydata[3] * 13);
  gAIL = (int16_t)((joydata[4] - 128) * (-13));
  gELE = (int16_t)((joydata[5] - 128) * 13);
  rc_enable_motor = (joydata[7] & 0x04u) ? 1 : 0;
  rc_connection_flag = connected ? 1 : 0;
  if (!connected) {
    gTHR = 0;
    rc_enable_motor = 0;
  }
}

#if !PRINTF_EVERY_LOOP
static void link_init(void) {
  stv_link_config_t cfg;
  memset(&cfg, 0, sizeof cfg);
  cfg.kp_ground = AHRS_KP_BIG;
  cfg.kp_flight = AHRS_KP_NORM;
  cfg.ki = AHRS_KI;
  cfg.dt_s = SENSOR_SAMPLING_TIME;
  cfg.min_thr = MIN_THR;
  cfg.cpu_hz = 84000000u;
  cfg.baud = STV_BAUD;
  cfg.flags = AHRS_NO_CORRECTION ? STV_FLAG_NO_CORRECTION : 0u;
  if (AHRS_VARIANT == 221117) cfg.flags |= STV_FLAG_FRESH_SQUARES; /* the status frames name 221117's filter */
  cfg.text_mode = STV_TEXT_MODE;
  cfg.text_decimation = STV_TEXT_DECIMATION;
  cfg.status_every = STV_STATUS_EVERY_STEPS;
  cfg.fc_every = STV_FC_EVERY;
  cfg.q_state[0] = &q0;
  cfg.q_state[1] = &q1;
  cfg.q_state[2] = &q2;
  cfg.q_state[3] = &q3;
  cfg.int_state[0] = &exInt;
  cfg.int_state[1] = &eyInt;
  cfg.int_state[2] = &ezInt;
  stv_fw_init(&cfg);
}
#endif

int main(void) {
  hw_clock_init();
  hw_systick_init();
  hw_gpio_init();
  hw_usart1_init(STV_BAUD);
#if !PRINTF_EVERY_LOOP
  link_init();
#endif
  log_line("steval-link reference firmware (not ST's): the STEVAL loop for tests and teaching\n");
  hw_spi2_init();
  hw_adc1_init();
  hw_tim4_pwm_init();
  if (imu_init() != 0) {
    log_line("LSM6DSL not found: stopped\n");
    for (;;) hw_sleep_until_irq();
  }
  log_line("LSM6DSL ready: acc +-4 g, gyro +-2000 dps\n");
  hw_delay_ms(1000u); /* let the sensors settle */
  log_line("calibrating the offsets for 2 s: keep the drone still\n");
  hw_tim9_start();
#if PRINTF_EVERY_LOOP
  uint32_t pass = 0u;
#endif

  for (;;) {
#if !SLEEP
    while (!tim9_event_flag) { /* SLEEP=0: poll, never sleep */
    }
#endif
    __asm__ volatile("cpsid i" ::: "memory");
    if (!tim9_event_flag) { /* nothing to do: sleep until the next interrupt, then take it */
      hw_sleep_until_irq();
      __asm__ volatile("cpsie i" ::: "memory");
      continue;
    }
    tim9_event_flag = 0u;
    average(acc_step, &acc_ahrs);
    average(gyro_step, &gyro_ahrs);
    __asm__ volatile("cpsie i" ::: "memory");

#if LINK_OUTPUT
    stv_fw_step_begin(gTHR);
#endif
    ahrs_fusion_ag(&acc_ahrs, &gyro_ahrs, &ahrs);
    QuaternionToEuler(&ahrs, &euler_ahrs);
#if LINK_OUTPUT
    stv_fw_step_end((const float *)&acc_ahrs, (const float *)&gyro_ahrs, (const float *)&ahrs,
                    (const float *)&euler_ahrs);
#endif
#if PRINTF_EVERY_LOOP
    print_loop_line(pass++);
#endif

    read_remote();
    VBAT = (float)(((hw_adc1_read() * 3.3) / 4095) * (10.0 + 20.0) / 20.0); /* 10k / 20k divider */
    GetTargetEulerAngle(&euler_rc);
    if (gTHR < MIN_THR) euler_rc.thz = euler_ahrs.thz = 0.0f;
    FlightControlPID_OuterLoop(&euler_rc, &euler_ahrs);
#if STV_FC_EVERY > 0 && LINK_OUTPUT
    if (stv_fw_flight_due())
      stv_fw_flight((const float *)&euler_rc, gAIL, gELE, gRUD, gTHR, (const float *)&pid, (const float *)&motor_pwm,
                    VBAT,
                    (rc_enable_motor ? STV_FC_ARMED : 0u) | (rc_connection_flag ? STV_FC_RC_CONNECTED : 0u));
#endif
  }
}

/* steval-link firmware port for the STEVAL-FCU001V1 (STM32F401, USART1 on PA9/PA10, DWT cycle counter).
 *
 * The main loop calls stv_fw_step_begin()/stv_fw_step_end() around ahrs_fusion_ag + QuaternionToEuler; the
 * frames go into a RAM ring buffer that the USART1 TXE interrupt drains. Nothing here ever waits for the UART: a
 * frame that does not fit in the queue is dropped and counted (status frame, tx_dropped). The USART1 RX interrupt
 * puts received bytes in a small ring; stv_fw_step_end handles the complete command frames among them (stv_cmd.h)
 * between two AHRS steps.
 * Registers are addressed directly (no HAL/CMSIS headers needed), so this file cross-compiles on its own.
 */
#ifndef STV_FW_H
#define STV_FW_H

#include <stddef.h>
#include <stdint.h>

#include "stv_cmd.h"
#include "stv_config.h"
#include "stv_link.h"

#ifdef __cplusplus
extern "C" {
#endif

/* After MX_USART1_UART_Init (the HAL has configured pins, baud rate and the USART1 NVIC line). Starts the DWT
 * cycle counter (without resetting it) and the link; cfg->baud/cpu_hz/... describe the build (status frame). */
void stv_fw_init(const stv_link_config_t *cfg);

/* Right before ahrs_fusion_ag(&acc_ahrs, &gyro_ahrs, &ahrs); thr = gTHR. */
void stv_fw_step_begin(int16_t thr);

/* The gTHR ahrs_fusion_ag chose its gain with: the patched ahrs.c reads gTHR once into this variable, and
 * stv_fw_step_end sends it in the frame (not stv_fw_step_begin's snapshot: with REMOCON_PWM, TIM2's capture
 * interrupt writes gTHR at any time, also between two reads). */
extern int16_t stv_thr_used;

/* Right after QuaternionToEuler(&ahrs.q, &euler_ahrs): queue the step's frames and start the transmitter. */
void stv_fw_step_end(const float acc_mg[3], const float gyro_mdps[3], const float q[4], const float euler_rad[3]);

/* Right after FlightControlPID_OuterLoop: 1 when this step's flight-control frame is due (STV_FC_EVERY). */
int stv_fw_flight_due(void);

/* The flight-control frame of this step (call when stv_fw_flight_due() says so). euler_rc: the targets thx, thy,
 * thz passed to the outer loop (&euler_rc_fil.thx); the sticks gAIL, gELE, gRUD, gTHR; pid_s: &pid.x_s1 of ST's
 * P_PI_PIDControlTypeDef, whose stage outputs lie x_s1, x_s2, y_s1, y_s2, z_s1, z_s2 in this order; motor_pwm:
 * &motor_pwm.motor1_pwm (4 floats); vbat_v: VBAT; fc_flags: STV_FC_*. The inner-loop outputs and the motor PWM,
 * which the TIM9 ISR writes, are copied with interrupts masked, so they come from one and the same ISR run. */
void stv_fw_flight(const float euler_rc[3], int16_t ail, int16_t ele, int16_t rud, int16_t thr,
                   const volatile float *pid_s, const volatile float *motor_pwm, float vbat_v, uint16_t fc_flags);

/* Log text (PRINTF): gathered into lines, sent as text frames (binary mode) or plain lines (text mode).
 * Safe from any context (runs with interrupts masked for the few µs it takes). */
void stv_fw_log_write(const char *s, size_t n);

/* The USART1 interrupt handler's body (replaces HAL_UART_IRQHandler(&huart1) in stm32f4xx_it.c). */
void stv_fw_usart1_irq(void);

/* The filter settings the patched ahrs_fusion_ag reads at every step (kp_ground, kp_flight, ki, min_thr,
 * correction): the build's values from stv_fw_init on; host commands change them between two steps. */
extern stv_filter_t stv_filter;

/* Frames dropped since boot because the TX queue was full. */
uint32_t stv_fw_dropped(void);

#ifdef __cplusplus
}
#endif

#endif /* STV_FW_H */

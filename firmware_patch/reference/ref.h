/* Reference firmware: what its modules share (types, globals, functions). */
#ifndef REF_H
#define REF_H

#include <stdint.h>

#include "stv_config.h"

/* Build options beyond stv_config.h's (make variables AHRS_DIVERGE, SWAP_MOTORS). */
#ifndef AHRS_DIVERGE
#define AHRS_DIVERGE 0 /* 1: a refactor's bug in the quaternion update (halfT scales only the last term) */
#endif
#ifndef SLEEP
#define SLEEP 1 /* 0: the main loop polls instead of sleeping with wfi */
#endif
#ifndef PRINTF_EVERY_LOOP
#define PRINTF_EVERY_LOOP 0 /* 1: a text line per main-loop pass by blocking transmit (ST's unpatched loop), no frames */
#endif
#ifndef MISSING_SYSTICK
#define MISSING_SYSTICK 0 /* 1: SysTick_Handler left out: a weak alias of Default_Handler, as in ST's startup */
#endif
#ifndef AHRS_VARIANT
#define AHRS_VARIANT 170120 /* the filter arithmetic of ST's release 170120 (= 170318, 301117 beta) or 221117 */
#endif
#ifndef LINK_OUTPUT
#define LINK_OUTPUT 1 /* 0: no frames on USART1 (an unpatched build's silence; the attitude is read by symbol) */
#endif
#if PRINTF_EVERY_LOOP
#undef LINK_OUTPUT
#define LINK_OUTPUT 0 /* the text line takes USART1: no frames */
#endif
#ifndef SWAP_MOTORS
#define SWAP_MOTORS 0 /* e.g. 34: motor outputs 3 and 4 exchanged (a mixer renumbered for another frame) */
#endif

#define MIN_THR 200               /* below it: ground gain, motors off, yaw reset */
#define AHRS_KP_BIG 10.0f         /* filter gain on the ground */
#define AHRS_KP_NORM 0.4f         /* filter gain in flight */
#define SENSOR_SAMPLING_TIME 0.00625f /* the dt the filter integrates with, s */
#define PID_SAMPLING_TIME 0.00125f    /* the tick's dt (inner loop, yaw integration), s */
#define COE_MDPS_TO_RADPS 1.745329252e-5
#define FIFO_ORDER 5

typedef struct { float x, y, z; } axes_f;                /* acc mg or gyro mdps */
typedef struct { float q0, q1, q2, q3; } quat_f;
typedef struct { float thx, thy, thz; } euler_f;         /* rad: pitch (about x), roll (about y), yaw */
typedef struct { float m1, m2, m3, m4; } motors_f;       /* TIM4 counts of 2000 */
/* PID stage outputs in the order the flight-control frame reads them: x_s1, x_s2, y_s1, y_s2, z_s1, z_s2 */
typedef struct { float x_s1, x_s2, y_s1, y_s2, z_s1, z_s2; } pid_out_t;

/* ahrs.c */
extern float q0, q1, q2, q3, exInt, eyInt, ezInt;
void ahrs_fusion_ag(const axes_f *acc, const axes_f *gyro, quat_f *q_out);
void QuaternionToEuler(const quat_f *q, euler_f *e);

/* flight.c */
extern pid_out_t pid;
extern motors_f motor_pwm;
void GetTargetEulerAngle(euler_f *rc);
void FlightControlPID_OuterLoop(const euler_f *rc, const euler_f *ahrs);
void FlightControlPID_innerLoop(const float gyro_radps[3]);
void set_motor_pwm_zero(void);
void set_motor_pwm(void);

/* main.c: the sticks and flags */
extern int16_t gAIL, gELE, gTHR, gRUD;
extern int32_t rc_enable_motor;

/* hw.c */
extern volatile uint32_t uwTick;
void hw_clock_init(void);
void hw_systick_init(void);
void hw_delay_ms(uint32_t ms);
void hw_gpio_init(void);
void hw_usart1_init(uint32_t baud);
void hw_spi2_init(void);
void hw_adc1_init(void);
uint32_t hw_adc1_read(void);
void hw_tim4_pwm_init(void);
void hw_tim4_set(uint32_t ch, uint32_t counts);
void hw_tim9_start(void);
void hw_sleep_until_irq(void);

/* imu.c: LSM6DSL over SPI2 */
int imu_init(void);
void imu_read(int32_t acc_mg[3], int32_t gyro_mdps[3]);
uint8_t Sensor_IO_Read(void *handle, uint8_t reg, uint8_t *buf, uint16_t n);
uint8_t Sensor_IO_Write(void *handle, uint8_t reg, uint8_t *buf, uint16_t n);

#endif /* REF_H */

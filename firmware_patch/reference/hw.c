/* Reference firmware: clock, SysTick, GPIO, USART1, SPI2, ADC1, TIM4 and TIM9 at register level. */
#include "ref.h"
#include "regs.h"

volatile uint32_t uwTick; /* ms since SysTick started (the emulator may preset it at main) */

/* HSE 16 MHz -> PLL (M 16, N 336, P 4) -> 84 MHz core; APB1 42 MHz (timers 84 MHz), APB2 84 MHz. */
void hw_clock_init(void) {
  RCC_APB1ENR |= 1u << 28;         /* PWR */
  PWR_CR = (PWR_CR & ~(3u << 14)) | (2u << 14); /* regulator scale 2 (up to 84 MHz) */
  RCC_CR |= 1u << 16;              /* HSEON */
  while (!(RCC_CR & (1u << 17))) { /* HSERDY */
  }
  RCC_PLLCFGR = 16u | (336u << 6) | (1u << 16) /* P = 4 */ | (1u << 22) /* HSE */ | (7u << 24);
  RCC_CR |= 1u << 24;              /* PLLON */
  while (!(RCC_CR & (1u << 25))) { /* PLLRDY */
  }
  FLASH_ACR = 2u | (7u << 8);      /* 2 wait states, prefetch, I- and D-cache */
  RCC_CFGR = (RCC_CFGR & ~0xFCF3u) | (4u << 10) | 2u; /* APB1 /2, APB2 /1, system clock = PLL */
  while (((RCC_CFGR >> 2) & 3u) != 2u) {
  }
}

#if !MISSING_SYSTICK
void SysTick_Handler(void) { uwTick++; }
#endif

/* 1 ms tick, lowest priority. */
void hw_systick_init(void) {
  SYST_RVR = 84000u - 1u;
  SYST_CVR = 0u;
  SCB_SHPR3 |= 0xF0u << 24;
  SYST_CSR = 7u; /* core clock, interrupt, enable */
}

void hw_delay_ms(uint32_t ms) {
  uint32_t t0 = uwTick;
  while ((uint32_t)(uwTick - t0) < ms) __asm__ volatile("wfi");
}

/* Sleep until an interrupt is pending; the caller masks interrupts first (cpsid i) so that none is missed. */
void hw_sleep_until_irq(void) { __asm__ volatile("wfi"); }

static void pin_mode(uint32_t port, uint32_t pin, uint32_t mode, uint32_t af) {
  GPIO_MODER(port) = (GPIO_MODER(port) & ~(3u << (2u * pin))) | (mode << (2u * pin));
  GPIO_OSPEEDR(port) |= 3u << (2u * pin);
  GPIO_AFR(port, pin / 8u) = (GPIO_AFR(port, pin / 8u) & ~(0xFu << (4u * (pin % 8u)))) | (af << (4u * (pin % 8u)));
}

/* Sensor chip selects high (PA8 LSM6DSL, PB12 LIS2MDL, PC13 LPS22HB), SPI2 PB13 SCK / PB15 data,
 * USART1 PA9 TX / PA10 RX, TIM4 CH1..4 PB6..PB9, battery sense PB1 (ADC1 channel 9). */
void hw_gpio_init(void) {
  RCC_AHB1ENR |= 7u; /* GPIOA, B, C */
  GPIO_BSRR(GPIOA) = 1u << 8;
  GPIO_BSRR(GPIOB) = 1u << 12;
  GPIO_BSRR(GPIOC) = 1u << 13;
  pin_mode(GPIOA, 8u, 1u, 0u);
  pin_mode(GPIOB, 12u, 1u, 0u);
  pin_mode(GPIOC, 13u, 1u, 0u);
  pin_mode(GPIOB, 13u, 2u, 5u);
  pin_mode(GPIOB, 15u, 2u, 5u);
  pin_mode(GPIOA, 9u, 2u, 7u);
  pin_mode(GPIOA, 10u, 2u, 7u);
  for (uint32_t p = 6u; p <= 9u; p++) pin_mode(GPIOB, p, 2u, 2u);
  pin_mode(GPIOB, 1u, 3u, 0u);
}

/* 8N1, 16x oversampling: BRR = 84 MHz / baud. stv_fw_init turns the RX interrupt on. */
void hw_usart1_init(uint32_t baud) {
  RCC_APB2ENR |= 1u << 4;
  USART1_BRR = (84000000u + baud / 2u) / baud;
  USART1_CR1 = (1u << 13) | (1u << 3) | (1u << 2); /* UE, TE, RE */
  NVIC_IPR8(IRQ_USART1) = 0x00u;                   /* above TIM9: no received byte is lost */
  NVIC_ISER(IRQ_USART1 / 32u) = 1u << (IRQ_USART1 % 32u);
}

/* Master, 3-wire (one data line), mode 3, 84 MHz / 16. */
void hw_spi2_init(void) {
  RCC_APB1ENR |= 1u << 14;
  SPI2_CR1 = (1u << 15) | (1u << 14) | (1u << 9) | (1u << 8) | (3u << 3) | (1u << 2) | 3u; /* BIDI, out, SSM/SSI */
  SPI2_CR1 |= 1u << 6;                                                                    /* SPE */
}

void hw_adc1_init(void) {
  RCC_APB2ENR |= 1u << 8;
  ADC1_SMPR2 = 7u << 27; /* channel 9: 480 cycles */
  ADC1_SQR3 = 9u;
  ADC1_CR2 = 1u; /* ADON */
}

/* One conversion of the battery divider, 12-bit counts. */
uint32_t hw_adc1_read(void) {
  ADC1_CR2 |= 1u << 30; /* SWSTART */
  while (!(ADC1_SR & 2u)) { /* EOC */
  }
  return ADC1_DR & 0xFFFu;
}

/* 1 MHz counter, 2000 counts (500 Hz), PWM mode 1 on CH1..4. */
void hw_tim4_pwm_init(void) {
  RCC_APB1ENR |= 1u << 2;
  TIM_PSC(TIM4) = 84u - 1u;
  TIM_ARR(TIM4) = 2000u - 1u;
  TIM_CCMR1(TIM4) = (6u << 4) | (1u << 3) | (6u << 12) | (1u << 11);
  TIM_CCMR2(TIM4) = (6u << 4) | (1u << 3) | (6u << 12) | (1u << 11);
  for (uint32_t ch = 1u; ch <= 4u; ch++) TIM_CCR(TIM4, ch) = 0u;
  TIM_CCER(TIM4) = 0x1111u;
  TIM_EGR(TIM4) = 1u;
  TIM_CR1(TIM4) = 1u;
}

void hw_tim4_set(uint32_t ch, uint32_t counts) { TIM_CCR(TIM4, ch) = counts; }

/* 84 MHz / 52 / 2000 = 807.69 Hz. The update generated here leaves UIF set: the first tick comes at once. */
void hw_tim9_start(void) {
  RCC_APB2ENR |= 1u << 16;
  TIM_PSC(TIM9) = 52u - 1u;
  TIM_ARR(TIM9) = 2000u - 1u;
  TIM_EGR(TIM9) = 1u;
  TIM_DIER(TIM9) = 1u; /* UIE */
  NVIC_IPR8(IRQ_TIM9) = 0x10u;
  NVIC_ISER(IRQ_TIM9 / 32u) = 1u << (IRQ_TIM9 % 32u);
  TIM_CR1(TIM9) = 1u;
}

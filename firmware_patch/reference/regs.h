/* Reference firmware: the STM32F401 registers it uses, by address (RM0368). Our own definitions, no ST headers. */
#ifndef REF_REGS_H
#define REF_REGS_H

#include <stdint.h>

#define REG(addr) (*(volatile uint32_t *)(addr))

/* RCC: clocks and peripheral clock enables */
#define RCC_CR REG(0x40023800u)
#define RCC_PLLCFGR REG(0x40023804u)
#define RCC_CFGR REG(0x40023808u)
#define RCC_AHB1ENR REG(0x40023830u)
#define RCC_APB1ENR REG(0x40023840u)
#define RCC_APB2ENR REG(0x40023844u)
#define FLASH_ACR REG(0x40023C00u)
#define PWR_CR REG(0x40007000u)

/* GPIO ports: MODER, OSPEEDR, ODR, BSRR, AFR[2] */
#define GPIOA 0x40020000u
#define GPIOB 0x40020400u
#define GPIOC 0x40020800u
#define GPIO_MODER(p) REG((p) + 0x00u)
#define GPIO_OSPEEDR(p) REG((p) + 0x08u)
#define GPIO_BSRR(p) REG((p) + 0x18u)
#define GPIO_AFR(p, i) REG((p) + 0x20u + 4u * (i))

/* timers: TIM4 (motor PWM), TIM9 (the 807.7 Hz tick) */
#define TIM4 0x40000800u
#define TIM9 0x40014000u
#define TIM_CR1(t) REG((t) + 0x00u)
#define TIM_DIER(t) REG((t) + 0x0Cu)
#define TIM_SR(t) REG((t) + 0x10u)
#define TIM_EGR(t) REG((t) + 0x14u)
#define TIM_CCMR1(t) REG((t) + 0x18u)
#define TIM_CCMR2(t) REG((t) + 0x1Cu)
#define TIM_CCER(t) REG((t) + 0x20u)
#define TIM_PSC(t) REG((t) + 0x28u)
#define TIM_ARR(t) REG((t) + 0x2Cu)
#define TIM_CCR(t, ch) REG((t) + 0x30u + 4u * (ch)) /* ch 1..4 */

/* USART1 (the link), SPI2 (the sensors), ADC1 (the battery) */
#define USART1_SR REG(0x40011000u)
#define USART1_DR REG(0x40011004u)
#define USART1_BRR REG(0x40011008u)
#define USART1_CR1 REG(0x4001100Cu)
#define SPI2_CR1 REG(0x40003800u)
#define SPI2_SR REG(0x40003808u)
#define SPI2_DR REG(0x4000380Cu)
#define ADC1_SR REG(0x40012000u)
#define ADC1_CR2 REG(0x40012008u)
#define ADC1_SMPR2 REG(0x40012010u)
#define ADC1_SQR3 REG(0x40012034u)
#define ADC1_DR REG(0x4001204Cu)

/* core: SysTick, NVIC, SCB */
#define SYST_CSR REG(0xE000E010u)
#define SYST_RVR REG(0xE000E014u)
#define SYST_CVR REG(0xE000E018u)
#define NVIC_ISER(n) REG(0xE000E100u + 4u * (n))
#define NVIC_IPR8(irq) (*(volatile uint8_t *)(0xE000E400u + (irq)))
#define SCB_SHPR3 REG(0xE000ED20u)
#define SCB_CPACR REG(0xE000ED88u)

#define IRQ_TIM9 24u
#define IRQ_USART1 37u

#endif /* REF_REGS_H */

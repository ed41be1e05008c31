/* Reference firmware: reset handler and vector table of the STM32F401 (16 core exceptions + 85 interrupts). */
#include <stdint.h>

#include "regs.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);

/* Copy .data from flash, zero .bss, turn the FPU on, run main. */
void Reset_Handler(void) {
  uint32_t *src = &_sidata, *dst = &_sdata;
  while (dst < &_edata) *dst++ = *src++;
  for (dst = &_sbss; dst < &_ebss;) *dst++ = 0u;
  SCB_CPACR |= 0xFu << 20; /* CP10, CP11: full access */
  __asm__ volatile("dsb\n\tisb");
  main();
  for (;;) {
  }
}

/* An interrupt without a handler, or a fault: stop here (the emulator reports these names). */
void Default_Handler(void) {
  for (;;) {
  }
}
void HardFault_Handler(void) {
  for (;;) {
  }
}

#if defined(MISSING_SYSTICK) && MISSING_SYSTICK
/* ST's startup names every vector, each a weak alias of Default_Handler until the firmware defines it */
#define WEAK_DEFAULT __attribute__((weak, alias("Default_Handler")))
void NMI_Handler(void) WEAK_DEFAULT;
void SVC_Handler(void) WEAK_DEFAULT;
void PendSV_Handler(void) WEAK_DEFAULT;
void SysTick_Handler(void) WEAK_DEFAULT;
void DMA1_Stream3_IRQHandler(void) WEAK_DEFAULT;
void WWDG_IRQHandler(void) WEAK_DEFAULT;
#else
void SysTick_Handler(void);
#endif
void TIM1_BRK_TIM9_IRQHandler(void);
void USART1_IRQHandler(void);

typedef void (*vector_t)(void);

__attribute__((section(".isr_vector"), used)) const vector_t vector_table[16 + 85] = {
    [0] = (vector_t)&_estack,
    [1] = Reset_Handler,
    [2] = Default_Handler,   /* NMI */
    [3] = HardFault_Handler,
    [4] = HardFault_Handler, /* MemManage */
    [5] = HardFault_Handler, /* BusFault */
    [6] = HardFault_Handler, /* UsageFault */
    [11] = Default_Handler,  /* SVCall */
    [14] = Default_Handler,  /* PendSV */
    [15] = SysTick_Handler,
    [16 ... 16 + IRQ_TIM9 - 1] = Default_Handler,
    [16 + IRQ_TIM9] = TIM1_BRK_TIM9_IRQHandler,
    [16 + IRQ_TIM9 + 1 ... 16 + IRQ_USART1 - 1] = Default_Handler,
    [16 + IRQ_USART1] = USART1_IRQHandler,
    [16 + IRQ_USART1 + 1 ... 16 + 84] = Default_Handler,
};

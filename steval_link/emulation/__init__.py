"""Firmware in the loop: ST's real flight-controller firmware (an ELF) on an emulated STM32F401 board.

- :mod:`~steval_link.emulation.elf`: load an ELF's segments and symbols (no toolchain needed).
- :mod:`~steval_link.emulation.board`: the board (unicorn Cortex-M4 + NVIC, SysTick, DWT, RCC, GPIO, TIM9, USART1,
  ADC1... as register models) and the function-level replacements (``Sensor_IO_Read/Write``, ``hci_send_req``).
- :mod:`~steval_link.emulation.sensors`: LSM6DSL, LIS2MDL and LPS22HB register models fed by a motion profile.
- :mod:`~steval_link.emulation.runner`: feed motion, run for a duration, yield USART1 bytes with emulated times.
"""

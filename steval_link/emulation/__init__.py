"""What stands in for the drone: the sensor model and motion, BROAD trials, the Lab 5 simulator, ``steval synth``
(the whole chain in Python) and firmware in the loop (ST's real firmware ELF on an emulated STM32F401 board).

- :mod:`~steval_link.emulation.sensor_model`, :mod:`~steval_link.emulation.motion`,
  :mod:`~steval_link.emulation.broad`: the LSM6DSL and the ISR pipeline, motion scenarios, real IMU trials.
- :mod:`~steval_link.emulation.synth` with :mod:`~steval_link.emulation.fw_link` and
  :mod:`~steval_link.emulation.usb_adapter`: emulated captures; :mod:`~steval_link.emulation.lab5`: the simulator.
- :mod:`~steval_link.emulation.elf`: load an ELF's segments and symbols (no toolchain needed).
- :mod:`~steval_link.emulation.board`: the board (unicorn Cortex-M4 + NVIC, SysTick, DWT, RCC, GPIO, TIM9, USART1,
  ADC1... as register models) and the function-level replacements (``Sensor_IO_Read/Write``, ``hci_send_req``).
- :mod:`~steval_link.emulation.sensors`: LSM6DSL, LIS2MDL and LPS22HB register models fed by a motion profile.
- :mod:`~steval_link.emulation.runner`: feed motion, run for a duration, yield USART1 bytes with emulated times.
"""

"""What stands in for the drone: the sensor model and motion, BROAD trials, the Lab 5 simulator, ``steval synth``
(the whole chain in Python) and firmware in the loop (ST's real firmware ELF on an emulated STM32F401 board,
:mod:`~steval_link.emulation.runner`). ``docs/ARCHITECTURE.md`` lists the modules.
"""

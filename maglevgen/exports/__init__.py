"""What leaves the toolchain for other tools, built on the analyses: the firmware folder
(``firmware``: the embedded controller's C, its schedule table and a CMake project for the
Cortex-M4F) and the FMU (``fmu``: FMI 2.0 and 3.0, model exchange and co-simulation).
"""

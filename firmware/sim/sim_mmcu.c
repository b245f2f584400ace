/* simavr metadata linked into the simulation build only: MCU, clock and supply voltages (mV). */
#include "avr_mcu_section.h"

AVR_MCU(F_CPU, "atmega2560");
AVR_MCU_VOLTAGES(5000, 5000, 5000);

/*
 * ap_law_step (firmware/aeropend/aeropend_control.h) on vectors from aeropend_core/testing/law_vectors.py, one
 * source for two builds (tests/test_firmware_sim.py runs both on the same vectors):
 *   host:  build/law_vectors          (the host C compiler; stdin -> stdout)
 *   AVR:   build/law_vectors_avr.elf  (avr-gcc, the firmware's flags; USART0 at 2 Mbaud, polled, run in simavr by
 *                                      build/law_runner, which feeds stdin to the UART and the UART to stdout)
 * Binary records in, little-endian float32:
 *   'C' + 13 f32          set the coefficients
 *   'V' + 6 f32 state + f32 reference + f32 feedforward + f32 angle
 *                         one law step; answers 7 f32 (duty, the 6 state elements after the step) + u8 branches
 *                         (bit 0 tripped, 1 unsaturated > u_max, 2 unsaturated < u_min, 3 conditional integration
 *                         held the integral)
 *   'T' + the same 9 f32  the same step, timed: answers u16 CPU cycles of the ap_law_step call (AVR: Timer1 at the
 *                         CPU clock; host: 0)
 *   'Q'                   end (the AVR build stops: cli + sleep, which ends simavr)
 */
#include <stdint.h>
#include <string.h>

#include "../aeropend/aeropend_control.h"

#ifdef __AVR__
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

static void io_init(void)
{
    UCSR0A = _BV(U2X0);
    UBRR0 = 0; /* 16 MHz / 8 = 2 Mbaud: only simavr is on the other end */
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0);
}
static int io_get(void)
{
    while (!(UCSR0A & _BV(RXC0)))
        ;
    return UDR0;
}
static void io_put(uint8_t byte)
{
    while (!(UCSR0A & _BV(UDRE0)))
        ;
    UDR0 = byte;
}
static void timer_start(void)
{
    TCCR1A = 0;
    TCCR1B = 0;
    TCNT1 = 0;
    TCCR1B = _BV(CS10); /* clk / 1 */
}
static uint16_t timer_stop(void)
{
    uint16_t t = TCNT1;
    TCCR1B = 0;
    return t;
}
static void io_end(void)
{
    while (!(UCSR0A & _BV(TXC0)) && !(UCSR0A & _BV(UDRE0)))
        ;
    cli();
    sleep_enable();
    sleep_cpu(); /* simavr: sleeping with interrupts off is the end of the program */
}
#else
#include <stdio.h>
static void io_init(void) {}
static int io_get(void) { return getchar(); }
static void io_put(uint8_t byte) { putchar(byte); }
static void io_end(void) { fflush(stdout); }
static void timer_start(void) {}
static uint16_t timer_stop(void) { return 0; }
#endif

static void get_floats(float *out, uint8_t count)
{
    uint8_t raw[4];
    for (uint8_t i = 0; i < count; i++) {
        for (uint8_t k = 0; k < 4; k++)
            raw[k] = (uint8_t)io_get();
        memcpy(&out[i], raw, 4);
    }
}

static void put_floats(const float *values, uint8_t count)
{
    uint8_t raw[4];
    for (uint8_t i = 0; i < count; i++) {
        memcpy(raw, &values[i], 4);
        for (uint8_t k = 0; k < 4; k++)
            io_put(raw[k]);
    }
}

int main(void)
{
    float c[AP_N_COEFFICIENTS] = {0};
    float s[AP_N_STATE];
    float inputs[3];
    float out[7];
    io_init();
    for (;;) {
        int kind = io_get();
        if (kind == 'C') {
            get_floats(c, AP_N_COEFFICIENTS);
        } else if (kind == 'V') {
            get_floats(s, AP_N_STATE);
            get_floats(inputs, 3);
            out[0] = ap_law_step(c, s, inputs[0], inputs[1], inputs[2]);
            for (uint8_t i = 0; i < AP_N_STATE; i++)
                out[1 + i] = s[i];
            /* The branches, from the values the step used (s[5] is its unsaturated output). */
            float error = inputs[0] - inputs[2];
            uint8_t branches = 0;
            if (s[4] != 0.0f)
                branches |= 1;
            else {
                if (s[5] > c[7])
                    branches |= 2;
                if (s[5] < c[6])
                    branches |= 4;
                if (c[8] == 2.0f && ((s[5] > c[7] && error > 0.0f) || (s[5] < c[6] && error < 0.0f)))
                    branches |= 8;
            }
            put_floats(out, 7);
            io_put(branches);
        } else if (kind == 'T') {
            get_floats(s, AP_N_STATE);
            get_floats(inputs, 3);
            timer_start();
            volatile float duty = ap_law_step(c, s, inputs[0], inputs[1], inputs[2]);
            uint16_t cycles = timer_stop();
            (void)duty;
            io_put((uint8_t)cycles);
            io_put((uint8_t)(cycles >> 8));
        } else {
            break; /* 'Q' or the end of the input */
        }
    }
    io_end();
    return 0;
}

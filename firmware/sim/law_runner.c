/*
 * law_runner: run a polled-UART AVR program (build/law_vectors_avr.elf) in simavr as a filter: stdin is fed into
 * USART0 as fast as the UART takes it (simavr's XON/XOFF on its input FIFO), everything USART0 sends goes to stdout.
 * Ends when the program sleeps with interrupts off (simavr: cpu_Done) or crashes; prints the simulated time and
 * cycle count on stderr. No pty, no pacing to the wall clock.
 *
 *   law_runner PROGRAM.elf < input > output
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_irq.h"

#define REG_UCSR0B 0xC1 /* ATmega2560 data-space address */
#define BIT_RXEN0 4

static uint8_t *out_buffer;
static size_t out_length, out_capacity;
static int uart_xon = 1;

static void output_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (out_length == out_capacity) {
        out_capacity = out_capacity ? 2 * out_capacity : 1 << 16;
        out_buffer = realloc(out_buffer, out_capacity);
        if (!out_buffer)
            exit(3);
    }
    out_buffer[out_length++] = (uint8_t)value;
}
static void xon_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xon = 1;
}
static void xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xon = 0;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s PROGRAM.elf < input > output\n", argv[0]);
        return 2;
    }
    /* the whole input first */
    size_t in_capacity = 1 << 16, in_length = 0, in_next = 0;
    uint8_t *in_buffer = malloc(in_capacity);
    size_t n;
    while (in_buffer && (n = fread(in_buffer + in_length, 1, in_capacity - in_length, stdin)) > 0) {
        in_length += n;
        if (in_length == in_capacity)
            in_buffer = realloc(in_buffer, in_capacity *= 2);
    }
    if (!in_buffer)
        return 3;

    /* simavr's loader prints to stdout: keep the real stdout for the program's bytes, send the rest to stderr */
    fflush(stdout);
    int out_fd = dup(STDOUT_FILENO);
    dup2(STDERR_FILENO, STDOUT_FILENO);

    elf_firmware_t firmware;
    memset(&firmware, 0, sizeof(firmware));
    if (elf_read_firmware(argv[1], &firmware) != 0) {
        fprintf(stderr, "law_runner: cannot read %s\n", argv[1]);
        return 1;
    }
    strcpy(firmware.mmcu, "atmega2560");
    firmware.frequency = 16000000;
    avr_t *avr = avr_make_mcu_by_name(firmware.mmcu);
    if (!avr)
        return 1;
    avr_init(avr);
    avr_load_firmware(avr, &firmware);
    avr->log = LOG_ERROR;
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_t *input = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), output_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), xon_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), xoff_hook, NULL);

    int state = cpu_Running;
    while (state != cpu_Done && state != cpu_Crashed) {
        /* feed once the program has enabled the receiver (simavr drops bytes before) */
        if (uart_xon && in_next < in_length && (avr->data[REG_UCSR0B] & (1 << BIT_RXEN0)))
            avr_raise_irq(input, in_buffer[in_next++]);
        state = avr_run(avr);
    }
    fflush(stdout);
    for (size_t done = 0; done < out_length;) {
        ssize_t written = write(out_fd, out_buffer + done, out_length - done);
        if (written <= 0)
            return 3;
        done += (size_t)written;
    }
    fprintf(stderr, "law_runner: %s after %.6f s simulated (%llu cycles), %zu of %zu bytes fed, %zu bytes out\n",
            state == cpu_Done ? "done" : "crashed", (double)avr->cycle / avr->frequency,
            (unsigned long long)avr->cycle, in_next, in_length, out_length);
    return state == cpu_Done ? 0 : 1;
}

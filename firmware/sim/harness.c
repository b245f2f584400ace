/*
 * aeropend_harness: run the aeropend firmware in simavr, in real time, with its UART0 on a pseudo-terminal.
 *
 *   aeropend_harness FIRMWARE.elf [--link PATH] [--adc CH=MILLIVOLTS]... [--pwm-to-adc CH] [--current-channel CH]
 *                    [--speed FACTOR]
 *
 * - Opens its own pty with openpty() (no fixed /tmp/simavr-uart0 symlink, so several harnesses can run at once),
 *   prints "pty <slave path>" on stdout, and optionally makes PATH a symlink to the slave (a stable device name
 *   such as /dev/serial/by-id/... on the rig). The harness keeps the slave open itself, so a reader can close and
 *   reopen the port.
 * - Bridges the firmware's UART0 both ways: bytes written by the firmware go to the pty master (dropped when
 *   nobody reads and the pty is full, like a USB CDC link), bytes from the host are fed into the UART receiver
 *   while it signals XON.
 * - Drives the ADC inputs: --adc CH=MV holds analog input CH at MV millivolts (AVCC = 5000 mV). At run time, lines
 *   "adc CH MV" on stdin change them; "quit", SIGTERM/SIGINT or the end of a piped stdin end the simulation.
 * - Measures the PWM on OC1A (PB5, Arduino D11) edge by edge and prints
 *   "pwm <sim_time_s> <duty> <freq_hz> <high> <low> <delay_min_us> <delay_max_us> <wall_s>" every 0.5 s of
 *   simulated time (wall_s: CLOCK_MONOTONIC, to see whether the simulation keeps real time):
 *   the duty over the last 0.5 s; how many sample-and-holds of the current channel (--current-channel, default 0)
 *   fell while the PWM output was high / low (the rig samples while it is high, docs/model.md section 1); and the shortest / longest
 *   time from the Timer1 overflow to that sample-and-hold [us] (-1 when none). simavr reports when a conversion
 *   starts; the sample-and-hold instant is placed after it by the ATmega2560 datasheet's fixed delays: an
 *   auto-triggered conversion holds 2 ADC clocks + 3 CPU cycles after its trigger, one started by writing ADSC
 *   1.5 ADC clocks after it (at the earliest: the prescaler is not reset then). --pwm-to-adc CH also feeds that
 *   duty (times 5000 mV) into analog input CH, standing in for an RC-filtered armature-voltage divider.
 * - ADC auto-trigger: simavr 1.6 implements only the free-running trigger ("unimplemented auto trigger mode").
 *   The harness wires the missing one as the chip does: on each rising edge of the Timer1 overflow flag, when the
 *   firmware has set ADATE and ADTS2:0 = 110 (Timer/Counter1 Overflow), it raises the ADC's trigger input, which
 *   starts a conversion unless one is running. A firmware that does not configure the trigger gets no conversion.
 * - --phase-correct-timer1: a model of Timer1 in mode 10 (phase-correct PWM, TOP = ICR1), which simavr 1.6 lacks
 *   (it falls back to overflows at ~9.3 kHz and no PWM). simavr's own Timer1 overflow interrupt is silenced and the
 *   harness raises it instead, at BOTTOM every 2 x ICR1 timer ticks, while the firmware has mode 10 and a clock
 *   selected (CS12:0; prescaler 1/8/64/256/1024); it drives OC1A (PB5) high while TCNT1 < OCR1A, i.e. for
 *   OCR1A ticks either side of BOTTOM (non-inverting COM1A1), with OCR1A latched at TOP (double-buffered). So the
 *   shipped build runs in the loop: frames, duty on the pin and the sampling instant can be measured. At each TOP
 *   it sets ICF1 in TIFR1, as the chip does when ICR1 is TOP.
 * - --dump-registers SECONDS: run that long in simulated time, print "reg NAME VALUE" for the Timer1 and ADC
 *   set-up registers (TCCR1A, TCCR1B, ICR1, OCR1A, TIMSK1, ADMUX, ADCSRA, ADCSRB) and exit; this works for the
 *   shipped phase-correct build too, whose timer simavr 1.6 does not run.
 * - Paces the simulation to the wall clock (FACTOR 1 = real time; 0 = as fast as possible).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <pty.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_adc.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_interrupts.h"
#include "sim_irq.h"

static volatile sig_atomic_t stop_requested;
static void on_signal(int sig) { (void)sig; stop_requested = 1; }

/* firmware -> host bytes waiting to be written to the pty master */
static uint8_t out_buffer[1 << 16];
static size_t out_length;
static unsigned long out_dropped;
/* host -> firmware bytes waiting for the UART */
static uint8_t in_buffer[4096];
static size_t in_start, in_length;
static int uart_xon = 1;

static void uart_output_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (out_length < sizeof(out_buffer))
        out_buffer[out_length++] = (uint8_t)value;
    else
        out_dropped++;
}
static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xon = 1;
}
static void uart_xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xon = 0;
}

/* PWM measurement on PB5 */
static avr_t *avr;
static int pwm_level;
static avr_cycle_count_t pwm_last_edge, pwm_high_cycles, pwm_window_start;
static unsigned long pwm_rising_edges;
static int pwm_adc_channel = -1;
static avr_irq_t *adc_irq_base;

/* ATmega2560 data-space addresses and bits (datasheet, register summary) */
#define REG_TIMSK1 0x6F
#define REG_ADCL 0x78
#define REG_ADCSRA 0x7A
#define REG_ADCSRB 0x7B
#define REG_ADMUX 0x7C
#define REG_TCCR1A 0x80
#define REG_TCCR1B 0x81
#define REG_ICR1L 0x86
#define REG_OCR1AL 0x88
#define BIT_ADATE 5
#define TIMER1_OVF_VECTOR 20
#define ADTS_TIMER1_OVERFLOW 6

/* Sample-and-holds of the current channel while PB5 was high / low (the paper's timing diagram), and their delay
 * after the Timer1 overflow. */
static int current_channel = 0;
static unsigned long trigger_high, trigger_low;
static avr_irq_t *adc_trigger_in;
static avr_cycle_count_t overflow_cycle;         /* last rising edge of the Timer1 overflow flag */
static int hold_pending;
static avr_cycle_count_t hold_cycle;             /* when the pending sample-and-hold happens */
static double hold_delay_min_us = -1, hold_delay_max_us = -1;

static void resolve_hold(int level)
{
    hold_pending = 0;
    if (level)
        trigger_high++;
    else
        trigger_low++;
}

static void adc_trigger_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    union { avr_adc_mux_t mux; uint32_t v; } event = { .v = value };
    if (event.mux.kind != ADC_MUX_SINGLE || (int)event.mux.src != current_channel)
        return;
    /* Auto-triggered (started in the cycle of the overflow, ADATE set): 2 ADC clocks + 3 CPU cycles; written ADSC:
     * 1.5 ADC clocks at the earliest. ADC clock = CPU clock / prescaler (ADPS2:0, 0 means 2). */
    uint8_t adps = avr->data[REG_ADCSRA] & 7;
    unsigned prescaler = adps ? 1u << adps : 2u;
    int automatic = avr->cycle == overflow_cycle && (avr->data[REG_ADCSRA] & (1 << BIT_ADATE));
    avr_cycle_count_t delay = automatic ? 2 * prescaler + 3 : 3 * prescaler / 2;
    if (hold_pending)
        resolve_hold(pwm_level);
    hold_pending = 1;
    hold_cycle = avr->cycle + delay;
    double after_overflow_us = (double)(hold_cycle - overflow_cycle) * 1e6 / avr->frequency;
    if (hold_delay_min_us < 0 || after_overflow_us < hold_delay_min_us)
        hold_delay_min_us = after_overflow_us;
    if (after_overflow_us > hold_delay_max_us)
        hold_delay_max_us = after_overflow_us;
}

/* The chip's ADC auto-trigger on Timer/Counter1 Overflow, which simavr 1.6 lacks (see the header comment). */
static void timer1_overflow_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (!value)
        return;
    overflow_cycle = avr->cycle;
    if ((avr->data[REG_ADCSRA] & (1 << BIT_ADATE)) && (avr->data[REG_ADCSRB] & 7) == ADTS_TIMER1_OVERFLOW) {
        avr_raise_irq(adc_trigger_in, 1);
        avr_raise_irq(adc_trigger_in, 0);
    }
}

/* Timer1 mode 10 model (--phase-correct-timer1, see the header comment) */
#define REG_TIFR1 0x36
#define BIT_ICF1 5
static avr_int_vector_t model_overflow;          /* replaces simavr's Timer1 overflow vector */
static avr_irq_t *pb5_irq;
static avr_cycle_count_t model_events[4];        /* pin high, BOTTOM, pin low, next TOP (absolute cycles) */
static int model_kinds[4], model_count, model_next;
enum { EVENT_HIGH, EVENT_BOTTOM, EVENT_LOW, EVENT_TOP };

static unsigned timer1_prescaler(void)
{
    static const unsigned prescalers[8] = {0, 1, 8, 64, 256, 1024, 0, 0};   /* 0: stopped or external clock */
    return prescalers[avr->data[REG_TCCR1B] & 7];
}

static int timer1_mode(void)
{
    return ((avr->data[REG_TCCR1B] >> 3) & 3) << 2 | (avr->data[REG_TCCR1A] & 3);
}

static void model_plan(avr_cycle_count_t top)
{
    /* one period from this TOP: OCR1A latched here; TCNT1 counts down TOP..0 (BOTTOM) and up again */
    unsigned icr = avr->data[REG_ICR1L] | (avr->data[REG_ICR1L + 1] << 8);
    unsigned ocr = avr->data[REG_OCR1AL] | (avr->data[REG_OCR1AL + 1] << 8);
    unsigned prescaler = timer1_prescaler();
    int running = timer1_mode() == 10 && prescaler && icr > 0;
    avr_cycle_count_t tick = prescaler ? prescaler : 64;
    if (!icr)
        icr = 255;
    model_count = model_next = 0;
    if (running && (avr->data[REG_TCCR1A] & 0x80)) {    /* COM1A1: non-inverting output on OC1A */
        if (ocr > icr)
            ocr = icr;
        if (ocr > 0) {
            model_events[model_count] = top + (icr - ocr) * tick;
            model_kinds[model_count++] = EVENT_HIGH;
        }
    }
    model_events[model_count] = top + icr * tick;
    model_kinds[model_count++] = running ? EVENT_BOTTOM : -1;
    if (running && (avr->data[REG_TCCR1A] & 0x80) && ocr > 0 && ocr < icr) {
        model_events[model_count] = top + (icr + ocr) * tick;
        model_kinds[model_count++] = EVENT_LOW;
    }
    model_events[model_count] = top + 2 * icr * tick;
    model_kinds[model_count++] = EVENT_TOP;
}

static avr_cycle_count_t timer1_model_event(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)param;
    int kind = model_kinds[model_next];
    avr_cycle_count_t at = model_events[model_next];
    model_next++;
    if (kind == EVENT_HIGH)
        avr_raise_irq(pb5_irq, 1);
    else if (kind == EVENT_LOW)
        avr_raise_irq(pb5_irq, 0);
    else if (kind == EVENT_BOTTOM)
        avr_raise_interrupt(avr, &model_overflow);
    else if (kind == EVENT_TOP) {
        /* ICR1 is TOP in mode 10: the chip sets ICF1 when the counter reaches it (the firmware's closed loop reads
         * it to know whether this period's OCR1A latch is still ahead) */
        if (timer1_mode() == 10)
            avr->data[REG_TIFR1] |= 1 << BIT_ICF1;
        model_plan(at);
    }
    if (model_next >= model_count)
        model_plan(at);   /* not reached: TOP is always last */
    (void)when;
    return model_events[model_next];
}

static int start_timer1_model(void)
{
    avr_int_table_p table = &avr->interrupts;
    avr_int_vector_t *simavr_overflow = NULL;
    for (int i = 0; i < table->vector_count; i++)
        if (table->vector[i]->vector == TIMER1_OVF_VECTOR)
            simavr_overflow = table->vector[i];
    if (!simavr_overflow)
        return -1;
    model_overflow.vector = TIMER1_OVF_VECTOR;
    model_overflow.enable = simavr_overflow->enable;   /* TIMSK1.TOIE1 */
    model_overflow.raised = simavr_overflow->raised;   /* TIFR1.TOV1 */
    simavr_overflow->vector = 0;                        /* simavr's raises of it now return at once */
    avr_register_vector(avr, &model_overflow);
    pb5_irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 5);
    model_plan(avr->cycle);
    avr_cycle_timer_register(avr, model_events[0] - avr->cycle, timer1_model_event, NULL);
    return 0;
}

static void pwm_pin_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    int level = value ? 1 : 0;
    if (level == pwm_level)
        return;
    avr_cycle_count_t now = avr->cycle;
    if (hold_pending && hold_cycle < now)
        resolve_hold(pwm_level);        /* the hold happened before this edge */
    if (pwm_level)
        pwm_high_cycles += now - pwm_last_edge;
    else
        pwm_rising_edges++;
    pwm_last_edge = now;
    pwm_level = level;
}

static double wall_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void pwm_report(void)
{
    avr_cycle_count_t now = avr->cycle;
    avr_cycle_count_t span = now - pwm_window_start;
    if (span == 0)
        return;
    avr_cycle_count_t high = pwm_high_cycles + (pwm_level ? now - pwm_last_edge : 0);
    double duty = (double)high / (double)span;
    double seconds = (double)span / avr->frequency;
    printf("pwm %.6f %.6f %.3f %lu %lu %.3f %.3f %.6f\n", (double)now / avr->frequency, duty,
           pwm_rising_edges / seconds, trigger_high, trigger_low, hold_delay_min_us, hold_delay_max_us,
           wall_seconds());
    trigger_high = trigger_low = 0;
    hold_delay_min_us = hold_delay_max_us = -1;
    fflush(stdout);
    if (pwm_adc_channel >= 0)
        avr_raise_irq(adc_irq_base + pwm_adc_channel, (uint32_t)(duty * 5000.0 + 0.5));
    pwm_window_start = now;
    pwm_last_edge = now;
    pwm_high_cycles = 0;
    pwm_rising_edges = 0;
}

static void sleep_hook(avr_t *a, avr_cycle_count_t how_long)
{
    (void)a; (void)how_long; /* pacing is done in the main loop */
}

static void set_adc(int channel, long millivolts)
{
    if (channel < 0 || channel > 15 || millivolts < 0 || millivolts > 5000) {
        fprintf(stderr, "harness: ignoring adc %d %ld (channel 0..15, 0..5000 mV)\n", channel, millivolts);
        return;
    }
    avr_raise_irq(adc_irq_base + channel, (uint32_t)millivolts);
}

static void handle_stdin_line(char *line)
{
    int channel;
    long millivolts;
    if (sscanf(line, "adc %d %ld", &channel, &millivolts) == 2)
        set_adc(channel, millivolts);
    else if (strncmp(line, "quit", 4) == 0)
        stop_requested = 1;
    else if (line[0] != '\0' && line[0] != '\n')
        fprintf(stderr, "harness: unknown command: %s", line);
}

static void dump_registers(void)
{
    printf("reg TCCR1A 0x%02x\n", avr->data[REG_TCCR1A]);
    printf("reg TCCR1B 0x%02x\n", avr->data[REG_TCCR1B]);
    printf("reg ICR1 %u\n", avr->data[REG_ICR1L] | (avr->data[REG_ICR1L + 1] << 8));
    printf("reg OCR1A %u\n", avr->data[REG_OCR1AL] | (avr->data[REG_OCR1AL + 1] << 8));
    printf("reg TIMSK1 0x%02x\n", avr->data[REG_TIMSK1]);
    printf("reg ADMUX 0x%02x\n", avr->data[REG_ADMUX]);
    printf("reg ADCSRA 0x%02x\n", avr->data[REG_ADCSRA]);
    printf("reg ADCSRB 0x%02x\n", avr->data[REG_ADCSRB]);
    fflush(stdout);
}

static void usage(const char *name)
{
    fprintf(stderr, "usage: %s FIRMWARE.elf [--link PATH] [--adc CH=MV]... [--pwm-to-adc CH] [--current-channel CH]"
            " [--speed FACTOR] [--phase-correct-timer1] [--dump-registers SECONDS]\n", name);
    exit(2);
}

int main(int argc, char **argv)
{
    const char *firmware_path = NULL, *link_path = NULL;
    double speed = 1.0;
    double dump_after = -1.0;
    int timer1_model = 0;
    int adc_channels[16];
    long adc_values[16];
    int adc_count = 0;

    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--link") && i + 1 < argc) {
            link_path = argv[++i];
        } else if (!strcmp(argv[i], "--adc") && i + 1 < argc && adc_count < 16) {
            if (sscanf(argv[++i], "%d=%ld", &adc_channels[adc_count], &adc_values[adc_count]) != 2)
                usage(argv[0]);
            adc_count++;
        } else if (!strcmp(argv[i], "--pwm-to-adc") && i + 1 < argc) {
            pwm_adc_channel = atoi(argv[++i]);
        } else if (!strcmp(argv[i], "--current-channel") && i + 1 < argc) {
            current_channel = atoi(argv[++i]);
        } else if (!strcmp(argv[i], "--speed") && i + 1 < argc) {
            speed = atof(argv[++i]);
        } else if (!strcmp(argv[i], "--phase-correct-timer1")) {
            timer1_model = 1;
        } else if (!strcmp(argv[i], "--dump-registers") && i + 1 < argc) {
            dump_after = atof(argv[++i]);
        } else if (argv[i][0] == '-' || firmware_path) {
            usage(argv[0]);
        } else {
            firmware_path = argv[i];
        }
    }
    if (!firmware_path)
        usage(argv[0]);

    elf_firmware_t firmware;
    memset(&firmware, 0, sizeof(firmware));
    if (elf_read_firmware(firmware_path, &firmware) != 0) {
        fprintf(stderr, "harness: cannot read firmware %s\n", firmware_path);
        return 1;
    }
    if (!firmware.mmcu[0])
        strcpy(firmware.mmcu, "atmega2560");
    if (!firmware.frequency)
        firmware.frequency = 16000000;
    avr = avr_make_mcu_by_name(firmware.mmcu);
    if (!avr) {
        fprintf(stderr, "harness: unknown MCU %s\n", firmware.mmcu);
        return 1;
    }
    avr_init(avr);
    avr_load_firmware(avr, &firmware);
    avr->vcc = avr->avcc = avr->aref = 5000;
    avr->sleep = sleep_hook;
    /* Errors only: simavr 1.6 warns on every ADCSRA write ("unimplemented auto trigger mode", which this harness
     * models) and, for the phase-correct build, on every OCR1A write ("mode 0 UNSUPPORTED"). */
    avr->log = LOG_ERROR;

    /* UART0 <-> pty */
    uint32_t uart_flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &uart_flags);
    uart_flags &= ~(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &uart_flags);
    avr_irq_t *uart_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_output_hook,
                            NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff_hook,
                            NULL);

    adc_irq_base = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0);
    for (int i = 0; i < adc_count; i++)
        set_adc(adc_channels[i], adc_values[i]);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 5), pwm_pin_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER), adc_trigger_hook, NULL);
    adc_trigger_in = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_IN_TRIGGER);
    if (timer1_model && start_timer1_model() != 0) {
        fprintf(stderr, "harness: no Timer1 overflow vector to replace in this MCU model\n");
        return 1;
    }
    avr_irq_t *overflow_irq = avr_get_interrupt_irq(avr, TIMER1_OVF_VECTOR);
    if (!overflow_irq || !adc_trigger_in) {
        fprintf(stderr, "harness: no Timer1 overflow interrupt or ADC trigger input in this MCU model\n");
        return 1;
    }
    avr_irq_register_notify(overflow_irq + AVR_INT_IRQ_PENDING, timer1_overflow_hook, NULL);

    if (dump_after >= 0) {
        const avr_cycle_count_t end = (avr_cycle_count_t)(dump_after * avr->frequency);
        int run_state = cpu_Running;
        while (avr->cycle < end && run_state != cpu_Done && run_state != cpu_Crashed)
            run_state = avr_run(avr);
        dump_registers();
        _exit(run_state == cpu_Crashed ? 1 : 0);
    }

    int master = -1, slave = -1;
    char slave_name[256];
    if (openpty(&master, &slave, slave_name, NULL, NULL) != 0) {
        perror("harness: openpty");
        return 1;
    }
    struct termios tio;
    tcgetattr(slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(slave, TCSANOW, &tio);
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    fcntl(STDIN_FILENO, F_SETFL, fcntl(STDIN_FILENO, F_GETFL) | O_NONBLOCK);
    if (link_path) {
        unlink(link_path);
        if (symlink(slave_name, link_path) != 0) {
            perror("harness: symlink");
            return 1;
        }
    }
    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    signal(SIGPIPE, SIG_IGN);
    printf("\npty %s\n", slave_name);
    fflush(stdout);

    const avr_cycle_count_t poll_cycles = avr->frequency / 10000;     /* host I/O every 100 us */
    const avr_cycle_count_t report_cycles = avr->frequency / 2;       /* PWM report every 0.5 s */
    avr_cycle_count_t next_poll = 0, next_report = report_cycles;
    double wall_start = wall_seconds();
    char line[256];
    size_t line_length = 0;
    int state = cpu_Running;
    struct stat stdin_stat;
    int stdin_open = 1;
    int stdin_is_pipe = fstat(STDIN_FILENO, &stdin_stat) == 0 && S_ISFIFO(stdin_stat.st_mode);

    while (!stop_requested && state != cpu_Done && state != cpu_Crashed) {
        state = avr_run(avr);
        if (hold_pending && avr->cycle > hold_cycle)
            resolve_hold(pwm_level);    /* no edge since the hold */
        if (avr->cycle < next_poll)
            continue;
        next_poll = avr->cycle + poll_cycles;

        /* firmware -> pty */
        if (out_length) {
            ssize_t n = write(master, out_buffer, out_length);
            if (n > 0) {
                memmove(out_buffer, out_buffer + n, out_length - (size_t)n);
                out_length -= (size_t)n;
            } else if (n < 0 && errno == EAGAIN && out_length > 4096) {
                out_dropped += out_length; /* nobody reads: drop like a USB link without a host */
                out_length = 0;
            }
        }
        /* pty -> firmware */
        if (in_length == 0) {
            ssize_t n = read(master, in_buffer, sizeof(in_buffer));
            if (n > 0) {
                in_start = 0;
                in_length = (size_t)n;
            }
        }
        if (in_length && uart_xon) {
            /* a few bytes per poll; the UART's own FIFO paces them at the baud rate */
            for (int k = 0; k < 4 && in_length && uart_xon; k++) {
                avr_raise_irq(uart_irq, in_buffer[in_start++]);
                in_length--;
            }
        }
        /* control lines on stdin */
        ssize_t n = stdin_open ? read(STDIN_FILENO, line + line_length, sizeof(line) - 1 - line_length) : -1;
        if (n == 0) {
            stdin_open = 0;
            if (stdin_is_pipe)
                stop_requested = 1; /* the controlling process went away */
        } else if (n > 0) {
            line_length += (size_t)n;
            line[line_length] = '\0';
            char *newline;
            while ((newline = strchr(line, '\n')) != NULL) {
                *newline = '\0';
                handle_stdin_line(line);
                size_t used = (size_t)(newline - line) + 1;
                memmove(line, line + used, line_length - used + 1);
                line_length -= used;
            }
            if (line_length >= sizeof(line) - 1)
                line_length = 0;
        }
        if (avr->cycle >= next_report) {
            next_report += report_cycles;
            pwm_report();
        }
        /* real-time pacing */
        if (speed > 0) {
            double ahead = (double)avr->cycle / avr->frequency / speed - (wall_seconds() - wall_start);
            if (ahead > 0.0005)
                usleep((useconds_t)(ahead * 1e6));
        }
    }
    if (link_path)
        unlink(link_path);
    fprintf(stderr, "harness: stopped at %.3f s simulated (state %d), %lu bytes dropped\n",
            (double)avr->cycle / avr->frequency, state, out_dropped);
    fflush(stderr);
    _exit(state == cpu_Crashed ? 1 : 0);
}

/*
 * aeropend firmware for the Arduino Mega 2560 + Arduino Motor Shield Rev3 (section 3 of the paper "Data-Driven
 * System Identification of an Aeropendulum"; docs/model.md section 1).
 *
 * - Timer1 drives the motor PWM on OC1A (D11) at 490.196 Hz, prescaler 64:
 *     default (real chip): phase-correct PWM, mode 10, TOP = ICR1 = 255  -> 16 MHz / (2 * 64 * 255);
 *     -DAEROPEND_FAST_PWM=1 (simavr 1.6 lacks phase-correct PWM): fast PWM, mode 14, TOP = ICR1 = 509
 *                                                                         -> 16 MHz / (64 * 510).
 *   Both give Ts = 2.04 ms. The Timer1 overflow (at BOTTOM, the centre of the pulse, in phase-correct mode; at the
 *   start of the pulse in fast mode) *auto-triggers* the current's ADC conversion in hardware (ADATE, ADTS = 110
 *   "Timer/Counter1 Overflow" in ADCSRB): the sample-and-hold closes 2 ADC clocks + 3 CPU cycles = 16.2 us after
 *   the overflow, whatever the CPU is doing, so the current is sampled inside the high pulse down to duty 0.016
 *   (phase-correct: duty x 1020 us of pulse remain after BOTTOM). Angle and voltage follow, chained through the
 *   ADC interrupt, then one SAMPLE frame. The overflow interrupt itself only writes precomputed values (the duty
 *   arithmetic runs when a command arrives, not in the interrupt).
 * - ADC (AVCC = 5 V reference, 10 bit, 125 kHz ADC clock):
 *     current: shield channel A sense on A0 (channel B: A1), 3.3 V <-> 2 A;
 *     angle:   A2, the AS5040's PWM output through a 2nd-order RC low-pass (R >= 4.7 kOhm, C >= 1 uF);
 *     voltage: A3, optional armature voltage divider (reads 0 when not fitted; the host then uses eq (8)).
 * - Shield channel A (default, as in the paper): DIR A = D12, BRAKE A = D9, sense A0. On the Mega the shield's
 *   PWM A pin (D3) is not a Timer1 output: bend the shield's D3 pin out and jumper D11 to it. Channel B
 *   (-DAEROPEND_SHIELD_CHANNEL_B=1) needs no jumper (PWM B = D11 = OC1A, DIR B = D13, BRAKE B = D8, sense A1).
 * - Serial: USART0 (USB), 250000 baud 8N1 (exact at 16 MHz), interrupt driven. Frame format: aeropend_protocol.h
 *   and aeropend_core/rig/protocol.py.
 * - Watchdog: when no valid command arrives for watchdog_ms (default 500 ms), the duty is cut to zero until the
 *   next SET_DUTY (closed loop: the next accepted SET_REFERENCE or SET_CONTROL_MODE 1). Maximum duty default 0.70
 *   (the paper's cap: the rod stays below 90 degrees).
 * - Closed loop (protocol version 2; open loop is the mode at boot): the controller law of aeropend_control.h (the
 *   single-precision mirror of aeropend_core/control/law.py's law_step) runs in the main loop once per sample, on
 *   the angle just sampled, (angle_counts - zero) * rad_per_count (SET_ANGLE_CALIBRATION; defaults 0 counts and
 *   2 pi / 1024 rad/count). Its duty, clamped to the maximum duty, is handed over like a SET_DUTY but written to
 *   OCR1A at once, so it applies from the next PWM period (see control_step). The law (at most ~3,500 cycles of
 *   soft float, 0.22 ms, measured in simavr), the duty's PWM setting (~70 us) and the CONTROL_SAMPLE frame take well
 *   under the 2.04 ms period, so it runs in the main loop with interrupts enabled, never in an interrupt. The 14
 *   coefficients come from the host (SET_CONTROL_COEFFICIENT, the layout of law.PidGains.coefficients at
 *   Ts = 2.04 ms); closed loop is refused until the first 13 have been set since boot (the 14th, the setpoint
 *   weight b in [0, 1], starts at 1: the plain PID). Every new command is answered by
 *   an ACK with a result code; non-finite values and inconsistent limits are refused. Safety: an angle outside
 *   [ANGLE_MIN, ANGLE_MAX] -> duty 0, latched (FLAG_LAW_TRIPPED) until the next accepted SET_REFERENCE or
 *   SET_CONTROL_MODE 1 (both restart the law: integral 0, derivative unprimed); the watchdog as above; SET_DUTY
 *   switches back to open loop; SET_CONTROL_MODE 0 sets the duty to 0. In closed loop every sample is sent as a
 *   CONTROL_SAMPLE (35 bytes on the wire: 68.6 % of 250000 baud at 490 Hz).
 *
 * Builds with the Arduino IDE / arduino-cli (board "Arduino Mega or Mega 2560") or with plain avr-gcc (Makefile).
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <util/atomic.h>

#include "aeropend_control.h"
#include "aeropend_protocol.h"

#ifndef F_CPU
#define F_CPU 16000000UL
#endif
#ifndef AEROPEND_BAUD
#define AEROPEND_BAUD 250000UL
#endif
#ifndef AEROPEND_FAST_PWM
#define AEROPEND_FAST_PWM 0
#endif
#ifndef AEROPEND_SIMAVR
#define AEROPEND_SIMAVR 0
#endif
#ifndef AEROPEND_SHIELD_CHANNEL_B
#define AEROPEND_SHIELD_CHANNEL_B 0
#endif
#ifndef AEROPEND_DEFAULT_MAX_DUTY_Q16
#define AEROPEND_DEFAULT_MAX_DUTY_Q16 45875U /* 0.70 * 65535 */
#endif
#ifndef AEROPEND_DEFAULT_WATCHDOG_MS
#define AEROPEND_DEFAULT_WATCHDOG_MS 500U
#endif

#if AEROPEND_FAST_PWM
#define PWM_TOP 509U
#define PWM_MODE AP_PWM_FAST
#else
#define PWM_TOP 255U
#define PWM_MODE AP_PWM_PHASE_CORRECT
#endif
#define SAMPLE_PERIOD_US 2040UL /* 64 * 510 / 16 MHz */
#define STATUS_EVERY_SAMPLES 490U

#if AEROPEND_SHIELD_CHANNEL_B
#define CURRENT_ADC_CHANNEL 1
#define DIR_DDR DDRB
#define DIR_PORT PORTB
#define DIR_BIT PB7 /* D13 */
#define BRAKE_DDR DDRH
#define BRAKE_PORT PORTH
#define BRAKE_BIT PH5 /* D8 */
#else
#define CURRENT_ADC_CHANNEL 0
#define DIR_DDR DDRB
#define DIR_PORT PORTB
#define DIR_BIT PB6 /* D12 (OC1B, used as a plain output) */
#define BRAKE_DDR DDRH
#define BRAKE_PORT PORTH
#define BRAKE_BIT PH6 /* D9 */
#endif
#define ANGLE_ADC_CHANNEL 2
#define VOLTAGE_ADC_CHANNEL 3

static const uint8_t adc_channels[3] = {CURRENT_ADC_CHANNEL, ANGLE_ADC_CHANNEL, VOLTAGE_ADC_CHANNEL};

/* ---- state shared between interrupts and the main loop ---- */
static volatile uint32_t sequence;              /* Timer1 overflows since reset */
static volatile uint16_t commanded_duty_q16;    /* after clamping; 0 when the watchdog tripped */
static volatile uint16_t applied_duty_q16;      /* the duty of the PWM period being sampled */
/* The next PWM period, precomputed in the main loop by duty_setting(): compare value, whether the pin is connected
 * to the timer (fast PWM disconnects it at duty 0), and the duty the pin really gets. */
static volatile uint16_t next_ocr;
static volatile uint8_t next_pin_on;
static volatile uint16_t next_applied_q16;
static volatile uint16_t max_duty_q16 = AEROPEND_DEFAULT_MAX_DUTY_Q16;
static volatile uint16_t watchdog_ms = AEROPEND_DEFAULT_WATCHDOG_MS;
static volatile uint16_t watchdog_ticks_left;   /* 0 = not armed (no command yet) */
static volatile uint8_t flags;                  /* AP_FLAG_* */
static volatile uint16_t rx_bad_frames;
static volatile uint16_t tx_dropped_frames;

/* sample being converted by the ADC chain */
static volatile uint8_t adc_index;
static volatile uint16_t adc_result[3];
static volatile uint32_t adc_sequence;
static volatile uint16_t adc_duty;

/* finished sample handed to the main loop */
static volatile uint8_t sample_ready;
static volatile uint32_t ready_sequence;
static volatile uint16_t ready_adc[3];
static volatile uint16_t ready_duty;
static volatile uint8_t status_due = 1;

/* ---- closed loop (main loop only: commands and the law both run there) ---- */
static uint8_t control_mode = AP_MODE_OPEN_LOOP;
/* Coefficients until the host sets them: zero gains inside the widest limits, setpoint weight 1 (the plain PID).
 * Closed loop is refused until each of the 13 before SETPOINT_WEIGHT has been set (law_set_mask covers LAW_ALL_SET);
 * the setpoint weight may be left at 1, so a host that sends only those 13 runs the law it knows. */
static float law_c[AP_N_COEFFICIENTS] = {0, 0, 0, 0, -1.0f, 1.0f, 0.0f, 1.0f, 0, 0, 0, -3.14159265f, 3.14159265f,
                                         1.0f};
static uint16_t law_set_mask;
#define LAW_ALL_SET ((1U << AP_C_SETPOINT_WEIGHT) - 1)
static float law_s[AP_N_STATE];
static float law_reference, law_feedforward;
static float angle_zero_counts = 0.0f;
static float angle_rad_per_count = 6.28318531f / 1024.0f;

/* ---- UART rings ---- */
#define TX_SIZE 256 /* power of two; uint8_t indices wrap */
static volatile uint8_t tx_buffer[TX_SIZE];
static volatile uint8_t tx_head, tx_tail;
#define RX_SIZE 64
static volatile uint8_t rx_buffer[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;

static uint16_t watchdog_ticks(uint16_t ms)
{
    uint32_t ticks = ((uint32_t)ms * 1000UL + SAMPLE_PERIOD_US - 1) / SAMPLE_PERIOD_US;
    return ticks ? (uint16_t)ticks : 1;
}

/* The PWM setting for a duty: compare value, pin connected, and the duty the pin really gets (q16). */
struct pwm_setting {
    uint16_t ocr;
    uint8_t pin_on;
    uint16_t applied_q16;
};

/* Compute the setting for `q16` (duty fraction * 65535): pure arithmetic (two 32-bit divisions, ~70 us), run in the
 * main loop with interrupts enabled, never in an interrupt or a critical section. */
static struct pwm_setting duty_setting(uint16_t q16)
{
    struct pwm_setting setting;
#if AEROPEND_FAST_PWM
    /* Fast PWM, non-inverting: duty = (OCR1A + 1) / (TOP + 1); OCR1A = 0 would still give a 1-tick pulse, so
     * duty 0 disconnects the pin (held low by PORTB). */
    uint16_t high = (uint16_t)(((uint32_t)q16 * (PWM_TOP + 1) + 32767UL) / 65535UL);
    setting.pin_on = high != 0;
    setting.ocr = high ? high - 1 : 0;
    setting.applied_q16 = (uint16_t)(((uint32_t)high * 65535UL) / (PWM_TOP + 1));
#else
    /* Phase-correct PWM, non-inverting: duty = OCR1A / TOP exactly (0 = always low, TOP = always high). */
    uint16_t ocr = (uint16_t)(((uint32_t)q16 * PWM_TOP + 32767UL) / 65535UL);
    setting.pin_on = 1;
    setting.ocr = ocr;
    setting.applied_q16 = (uint16_t)(((uint32_t)ocr * 65535UL) / PWM_TOP);
#endif
    return setting;
}

/* Hand a precomputed setting to the overflow interrupt (call with interrupts disabled). */
static inline void store_setting(const struct pwm_setting *setting)
{
    next_ocr = setting->ocr;
    next_pin_on = setting->pin_on;
    next_applied_q16 = setting->applied_q16;
}

/* Cut the motor from inside the interrupt (watchdog): no arithmetic. */
static inline void prepare_zero_duty(void)
{
    next_ocr = 0;
    next_pin_on = AEROPEND_FAST_PWM ? 0 : 1;
    next_applied_q16 = 0;
}

/* Write the precomputed compare value (takes effect from the next period on: OCR1A is double-buffered). */
static inline void pwm_apply(void)
{
#if AEROPEND_FAST_PWM
    if (!next_pin_on) {
        if (TCCR1A & _BV(COM1A1)) {
            TCCR1A &= (uint8_t)~_BV(COM1A1);
#if AEROPEND_SIMAVR
            /* simavr 1.6 keeps the pin at the timer's last level after disconnection; a PORT write updates it
             * (on the chip the pin already follows PORTB5 = 0; this pulse would last one CPU cycle). */
            PORTB |= _BV(PB5);
            PORTB &= (uint8_t)~_BV(PB5);
#endif
        }
        return;
    }
    OCR1A = next_ocr;
    TCCR1A |= _BV(COM1A1);
#else
    OCR1A = next_ocr;
#endif
}

static void tx_push(const uint8_t *data, uint8_t length)
{
    uint8_t used = (uint8_t)(tx_head - tx_tail);
    if ((uint16_t)used + length >= TX_SIZE) {
        /* No room for the whole frame: drop it (the host sees the sequence gap) and flag the next sample. */
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
            tx_dropped_frames++;
            flags |= AP_FLAG_SAMPLES_DROPPED;
        }
        return;
    }
    for (uint8_t i = 0; i < length; i++)
        tx_buffer[(uint8_t)(tx_head + i)] = data[i];
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        tx_head = (uint8_t)(tx_head + length);
        UCSR0B |= _BV(UDRIE0);
    }
}

ISR(USART0_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buffer[tx_tail];
    tx_tail = (uint8_t)(tx_tail + 1);
}

ISR(USART0_RX_vect)
{
    uint8_t status = UCSR0A;
    uint8_t byte = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1) % RX_SIZE);
    if (status & (_BV(FE0) | _BV(DOR0)))
        byte = 0xFF; /* corrupts the current command: its CRC fails */
    if (next != rx_tail) {
        rx_buffer[rx_head] = byte;
        rx_head = next;
    }
}

/* Timer1 overflow (the PWM output is high here). The hardware has already started the current's conversion on
 * this overflow (ADC auto-trigger), so nothing here is on the sampling's critical path. */
ISR(TIMER1_OVF_vect)
{
    uint32_t seq = sequence;
    sequence = seq + 1;
    adc_sequence = seq;
    adc_duty = applied_duty_q16;
    /* Watchdog: count down while armed; on expiry cut the motor. */
    if (watchdog_ticks_left) {
        if (--watchdog_ticks_left == 0) {
            commanded_duty_q16 = 0;
            prepare_zero_duty();
            flags |= AP_FLAG_WATCHDOG_TRIPPED;
        }
    }
    pwm_apply();
    applied_duty_q16 = next_applied_q16;
    TIFR1 = _BV(ICF1); /* TOP of this period not reached yet (control_step) */
    adc_index = 0;
}

/* Conversion complete: the current (auto-triggered), then angle and voltage started here by hand; ADMUX is back on
 * the current channel long before the next overflow triggers it. */
ISR(ADC_vect)
{
    uint8_t i = adc_index;
    adc_result[i] = ADC;
    i++;
    if (i < 3) {
        adc_index = i;
        ADMUX = _BV(REFS0) | adc_channels[i];
        ADCSRA |= _BV(ADSC);
        return;
    }
    adc_index = i;
    ADMUX = _BV(REFS0) | adc_channels[0];
    ready_sequence = adc_sequence;
    ready_duty = adc_duty;
    ready_adc[0] = adc_result[0];
    ready_adc[1] = adc_result[1];
    ready_adc[2] = adc_result[2];
    sample_ready = 1;
}

static void law_reset(void)
{
    for (uint8_t i = 0; i < AP_N_STATE; i++)
        law_s[i] = 0.0f;
}

/* Duty fraction -> q16, saturating (NaN -> 0). */
static uint16_t duty_q16_of(float duty)
{
    if (!(duty > 0.0f))
        return 0;
    if (duty >= 1.0f)
        return 65535U;
    return (uint16_t)(duty * 65535.0f + 0.5f);
}

/* One step of the law on sample `seq`'s angle; its duty applies from the next PWM period (seq + 1).
 *
 * A SET_DUTY goes through the overflow interrupt (pwm_apply at the next overflow, effective one period later). The
 * law writes OCR1A itself instead, during the sample's own period, so that its duty drives the very next period:
 * OCR1A is double-buffered and latched at BOTTOM (fast PWM: the next overflow) or at TOP (phase-correct: the middle
 * of this period, where the output is low; the latched value shapes the pulse centred on the next BOTTOM). It does
 * so only while that latch is still ahead: the period has not ended (sequence == seq + 1) and Timer1 has not
 * reached TOP (ICF1, set at TOP when ICR1 is TOP, cleared by the overflow interrupt). Otherwise, and in fast PWM when
 * the pin must be connected or disconnected (immediate, not buffered), the interrupt applies it one period later.
 * applied_duty_q16 follows the write, so SAMPLE's duty_q16 stays the duty of its own period. */
static void control_step(uint32_t seq, uint16_t angle_counts)
{
    uint8_t halted;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        halted = flags & AP_FLAG_WATCHDOG_TRIPPED;
    }
    if (halted)
        return; /* the watchdog cut the motor: the law waits for SET_REFERENCE or SET_CONTROL_MODE 1 */
    float angle = ((float)angle_counts - angle_zero_counts) * angle_rad_per_count;
    float duty = ap_law_step(law_c, law_s, law_reference, law_feedforward, angle);
    uint16_t wanted = duty_q16_of(duty);
    uint16_t limit = max_duty_q16;
    uint16_t q16 = wanted > limit ? limit : wanted;
    struct pwm_setting setting = duty_setting(q16);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        if (!(flags & AP_FLAG_WATCHDOG_TRIPPED)) { /* (it may have fired meanwhile) */
            commanded_duty_q16 = q16;
            store_setting(&setting);
            if (wanted > limit)
                flags |= AP_FLAG_DUTY_CLAMPED;
            else
                flags &= (uint8_t)~AP_FLAG_DUTY_CLAMPED;
            uint8_t latch_ahead = sequence == seq + 1 && !(TIFR1 & _BV(ICF1));
#if AEROPEND_FAST_PWM
            latch_ahead = latch_ahead && setting.pin_on && (TCCR1A & _BV(COM1A1));
#endif
            if (latch_ahead) {
                pwm_apply();
                applied_duty_q16 = setting.applied_q16;
            }
        }
    }
}

static uint8_t mode_flags(void)
{
    if (control_mode != AP_MODE_CLOSED_LOOP)
        return 0;
    return AP_FLAG_CLOSED_LOOP | (law_s[AP_S_TRIPPED] != 0.0f ? AP_FLAG_LAW_TRIPPED : 0);
}

static void send_sample(void)
{
    uint8_t payload[AP_CONTROL_SAMPLE_PAYLOAD];
    uint8_t wire[AP_CONTROL_SAMPLE_PAYLOAD + 5];
    uint32_t seq;
    uint16_t adc0, adc1, adc2, duty;
    uint8_t f;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        seq = ready_sequence;
        adc0 = ready_adc[0];
        adc1 = ready_adc[1];
        adc2 = ready_adc[2];
        duty = ready_duty;
        f = flags;
        flags = f & (uint8_t)~AP_FLAG_SAMPLES_DROPPED;
        sample_ready = 0;
    }
    uint8_t closed = control_mode == AP_MODE_CLOSED_LOOP;
    if (closed)
        control_step(seq, adc1);
    payload[0] = closed ? AP_MSG_CONTROL_SAMPLE : AP_MSG_SAMPLE;
    ap_put_u32(payload + 1, seq);
    ap_put_u16(payload + 5, adc0);
    ap_put_u16(payload + 7, adc1);
    ap_put_u16(payload + 9, adc2);
    ap_put_u16(payload + 11, duty);
    payload[13] = f | mode_flags();
    if (closed) {
        ap_put_f32(payload + 14, law_reference);
        ap_put_f32(payload + 18, law_feedforward);
        ap_put_f32(payload + 22, law_s[AP_S_UNSATURATED]);
        ap_put_f32(payload + 26, law_s[AP_S_INTEGRAL]);
    }
    tx_push(wire, ap_frame(payload, closed ? AP_CONTROL_SAMPLE_PAYLOAD : AP_SAMPLE_PAYLOAD, wire));
    if (seq % STATUS_EVERY_SAMPLES == STATUS_EVERY_SAMPLES - 1)
        status_due = 1;
}

static void send_status(void)
{
    uint8_t payload[AP_STATUS_PAYLOAD];
    uint8_t wire[AP_STATUS_PAYLOAD + 5];
    static uint8_t booted;
    uint8_t f;
    uint32_t seq;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        f = flags;
        seq = sequence;
        status_due = 0;
    }
    if (!booted) {
        f |= AP_FLAG_BOOT;
        booted = 1;
    }
    payload[0] = AP_MSG_STATUS;
    payload[1] = AP_PROTOCOL_VERSION;
    payload[2] = PWM_MODE;
    payload[3] = f | mode_flags();
    ap_put_u16(payload + 4, PWM_TOP);
    ap_put_u16(payload + 6, max_duty_q16);
    ap_put_u16(payload + 8, watchdog_ms);
    ap_put_u16(payload + 10, rx_bad_frames);
    ap_put_u16(payload + 12, tx_dropped_frames);
    ap_put_u32(payload + 14, seq);
    tx_push(wire, ap_frame(payload, AP_STATUS_PAYLOAD, wire));
}

static void handle_command(uint8_t kind, uint16_t value)
{
    /* The arithmetic first, with interrupts enabled (max_duty_q16 and watchdog_ms only change here). */
    uint16_t limit = max_duty_q16;
    uint16_t duty = kind == AP_CMD_SET_DUTY ? (value > limit ? limit : value) : value;
    struct pwm_setting setting = duty_setting(duty);
    uint8_t watchdog_valid = value >= 10 && value <= 60000;
    uint16_t ticks = watchdog_ticks(kind == AP_CMD_SET_WATCHDOG && watchdog_valid ? value : watchdog_ms);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        switch (kind) {
        case AP_CMD_SET_DUTY:
            control_mode = AP_MODE_OPEN_LOOP; /* SET_DUTY always wins: back to open loop */
            if (value > limit)
                flags |= AP_FLAG_DUTY_CLAMPED;
            else
                flags &= (uint8_t)~AP_FLAG_DUTY_CLAMPED;
            commanded_duty_q16 = duty;
            store_setting(&setting);
            flags &= (uint8_t)~AP_FLAG_WATCHDOG_TRIPPED;
            break;
        case AP_CMD_SET_MAX_DUTY:
            max_duty_q16 = value;
            if (commanded_duty_q16 > value) {
                commanded_duty_q16 = value;
                store_setting(&setting);
                flags |= AP_FLAG_DUTY_CLAMPED;
            }
            status_due = 1;
            break;
        case AP_CMD_SET_WATCHDOG:
            if (!watchdog_valid) {
                rx_bad_frames++;
                status_due = 1;
                return; /* rejected: does not feed the watchdog */
            }
            watchdog_ms = value;
            status_due = 1;
            break;
        case AP_CMD_REQUEST_STATUS:
            status_due = 1;
            break;
        default:
            rx_bad_frames++;
            return;
        }
        watchdog_ticks_left = ticks; /* every valid command feeds the watchdog */
    }
}

/* ---- the closed loop's commands, each answered by an ACK ---- */
static void send_ack(uint8_t command, uint8_t index, uint8_t result, float value)
{
    uint8_t payload[AP_ACK_PAYLOAD];
    uint8_t wire[AP_ACK_PAYLOAD + 5];
    payload[0] = AP_MSG_ACK;
    payload[1] = command;
    payload[2] = index;
    payload[3] = result;
    ap_put_f32(payload + 4, value);
    tx_push(wire, ap_frame(payload, AP_ACK_PAYLOAD, wire));
}

/* Whether `v` may become coefficient `index`, given the others as stored. */
static uint8_t coefficient_result(uint8_t index, float v)
{
    if (index >= AP_N_COEFFICIENTS)
        return AP_ACK_UNKNOWN_INDEX;
    if (!ap_f32_finite(v))
        return AP_ACK_OUT_OF_RANGE;
    uint8_t ok;
    switch (index) {
    case AP_C_P:
    case AP_C_I_TS:
    case AP_C_D_GAIN:
    case AP_C_AW_GAIN:
        ok = v >= 0.0f;
        break;
    case AP_C_D_POLE:
        ok = v >= 0.0f && v < 1.0f;
        break;
    case AP_C_I_MIN:
        ok = v <= law_c[AP_C_I_MAX];
        break;
    case AP_C_I_MAX:
        ok = v >= law_c[AP_C_I_MIN];
        break;
    case AP_C_U_MIN:
        ok = v >= 0.0f && v <= law_c[AP_C_U_MAX];
        break;
    case AP_C_U_MAX:
        ok = v >= law_c[AP_C_U_MIN] && v <= 1.0f;
        break;
    case AP_C_AW_CODE:
        ok = v == 0.0f || v == 1.0f || v == 2.0f;
        break;
    case AP_C_ANGLE_MIN:
        ok = v < law_c[AP_C_ANGLE_MAX];
        break;
    case AP_C_ANGLE_MAX:
        ok = v > law_c[AP_C_ANGLE_MIN];
        break;
    case AP_C_SETPOINT_WEIGHT:
        ok = v >= 0.0f && v <= 1.0f;
        break;
    default: /* FF_GAIN: any finite weight */
        ok = 1;
    }
    return ok ? AP_ACK_OK : AP_ACK_OUT_OF_RANGE;
}

/* Restart the law (integral 0, derivative unprimed, trip cleared) and lift a watchdog cut, in closed loop. */
static void law_restart(void)
{
    law_reset();
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        flags &= (uint8_t)~(AP_FLAG_WATCHDOG_TRIPPED | AP_FLAG_DUTY_CLAMPED);
    }
}

static void handle_control_command(const uint8_t *payload)
{
    uint8_t kind = payload[0];
    uint8_t index = 0, result = AP_ACK_OK;
    float value = 0.0f;
    if (kind == AP_CMD_SET_CONTROL_COEFFICIENT) {
        index = payload[1];
        float v = ap_get_f32(payload + 2);
        result = coefficient_result(index, v);
        if (result == AP_ACK_OK) {
            law_c[index] = v;
            law_set_mask |= (uint16_t)(1U << index);
            /* new integral limits hold from now on (as PidController.set_gains) */
            if (law_s[AP_S_INTEGRAL] > law_c[AP_C_I_MAX])
                law_s[AP_S_INTEGRAL] = law_c[AP_C_I_MAX];
            if (law_s[AP_S_INTEGRAL] < law_c[AP_C_I_MIN])
                law_s[AP_S_INTEGRAL] = law_c[AP_C_I_MIN];
        }
        if (result != AP_ACK_UNKNOWN_INDEX)
            value = law_c[index];
    } else if (kind == AP_CMD_SET_REFERENCE) {
        float reference = ap_get_f32(payload + 1), feedforward = ap_get_f32(payload + 5);
        if (!ap_f32_finite(reference) || !ap_f32_finite(feedforward) || feedforward < 0.0f || feedforward > 1.0f
            || reference < law_c[AP_C_ANGLE_MIN] || reference > law_c[AP_C_ANGLE_MAX]) {
            result = AP_ACK_OUT_OF_RANGE;
        } else {
            uint8_t halted;
            ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
                halted = flags & AP_FLAG_WATCHDOG_TRIPPED;
            }
            law_reference = reference;
            law_feedforward = feedforward;
            if (control_mode == AP_MODE_CLOSED_LOOP && (halted || law_s[AP_S_TRIPPED] != 0.0f))
                law_restart();
        }
        value = law_reference;
    } else if (kind == AP_CMD_SET_CONTROL_MODE) {
        uint16_t mode = (uint16_t)payload[1] | ((uint16_t)payload[2] << 8);
        if (mode == AP_MODE_OPEN_LOOP) {
            struct pwm_setting setting = duty_setting(0);
            control_mode = AP_MODE_OPEN_LOOP;
            ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
                commanded_duty_q16 = 0;
                store_setting(&setting);
            }
        } else if (mode != AP_MODE_CLOSED_LOOP) {
            result = AP_ACK_OUT_OF_RANGE;
        } else if ((law_set_mask & LAW_ALL_SET) != LAW_ALL_SET) {
            result = AP_ACK_REFUSED;
        } else {
            law_restart();
            control_mode = AP_MODE_CLOSED_LOOP;
        }
        value = (float)control_mode;
    } else { /* AP_CMD_SET_ANGLE_CALIBRATION */
        float zero = ap_get_f32(payload + 1), scale = ap_get_f32(payload + 5);
        if (!ap_f32_finite(zero) || !ap_f32_finite(scale) || scale == 0.0f) {
            result = AP_ACK_OUT_OF_RANGE;
        } else if (control_mode == AP_MODE_CLOSED_LOOP) {
            result = AP_ACK_REFUSED; /* the angle would jump under the running law */
        } else {
            angle_zero_counts = zero;
            angle_rad_per_count = scale;
        }
        value = angle_zero_counts;
    }
    if (result == AP_ACK_OK) {
        uint16_t ticks = watchdog_ticks(watchdog_ms);
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
            watchdog_ticks_left = ticks; /* an accepted command feeds the watchdog */
        }
    }
    send_ack(kind, index, result, value);
}

static uint8_t command_buffer[AP_MAX_WIRE];
static uint8_t command_length;
static uint8_t command_overflow;

static void receive_byte(uint8_t byte)
{
    if (byte != 0) {
        if (command_length < sizeof(command_buffer))
            command_buffer[command_length++] = byte;
        else
            command_overflow = 1;
        return;
    }
    /* delimiter: decode what came before it (empty chunks are the gap between two messages) */
    if (command_length == 0 && !command_overflow)
        return;
    int16_t n = command_overflow ? -1 : ap_cobs_decode(command_buffer, command_length);
    command_length = 0;
    command_overflow = 0;
    uint8_t kind = n > 0 ? command_buffer[0] : 0;
    int16_t expected = kind == AP_CMD_SET_CONTROL_COEFFICIENT ? AP_COEFFICIENT_PAYLOAD
        : (kind == AP_CMD_SET_REFERENCE || kind == AP_CMD_SET_ANGLE_CALIBRATION) ? AP_TWO_FLOAT_PAYLOAD
        : AP_COMMAND_PAYLOAD;
    if (n != expected + 2) {
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
            rx_bad_frames++;
        }
        return;
    }
    uint16_t crc = (uint16_t)command_buffer[expected] | ((uint16_t)command_buffer[expected + 1] << 8);
    if (ap_crc16(command_buffer, (uint8_t)expected) != crc) {
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
            rx_bad_frames++;
        }
        return;
    }
    if (kind == AP_CMD_SET_CONTROL_COEFFICIENT || kind == AP_CMD_SET_REFERENCE || kind == AP_CMD_SET_CONTROL_MODE
        || kind == AP_CMD_SET_ANGLE_CALIBRATION)
        handle_control_command(command_buffer);
    else
        handle_command(kind, (uint16_t)command_buffer[1] | ((uint16_t)command_buffer[2] << 8));
}

void setup(void)
{
    cli();
    /* Motor shield: direction forward, brake released, PWM pin D11 = PB5 = OC1A low until enabled. */
    DIR_DDR |= _BV(DIR_BIT);
    DIR_PORT &= (uint8_t)~_BV(DIR_BIT);
    BRAKE_DDR |= _BV(BRAKE_BIT);
    BRAKE_PORT &= (uint8_t)~_BV(BRAKE_BIT);
    DDRB |= _BV(PB5);
    PORTB &= (uint8_t)~_BV(PB5);

    /* Timer1: stop, configure, start (prescaler 64). COM1B/COM1C stay 0 so D12/D13 remain plain outputs. */
    TCCR1B = 0;
#if AEROPEND_FAST_PWM
    TCCR1A = _BV(WGM11);                          /* mode 14: fast PWM, TOP = ICR1 (pin connected when duty > 0) */
    TCCR1B = _BV(WGM13) | _BV(WGM12);
#else
    TCCR1A = _BV(COM1A1) | _BV(WGM11);            /* mode 10: phase-correct PWM, TOP = ICR1 */
    TCCR1B = _BV(WGM13);
#endif
    TCNT1 = 0;
    ICR1 = PWM_TOP;
    OCR1A = 0;
    TCCR1B |= _BV(CS11) | _BV(CS10);              /* start: prescaler 64 */
    TIFR1 = _BV(TOV1);
    TIMSK1 = _BV(TOIE1);

    /* ADC: AVCC reference, prescaler 128 (125 kHz), interrupt on completion, auto-triggered by the Timer1
     * overflow (ADTS2:0 = 110): the current's sample-and-hold is 2 ADC clocks + 3 CPU cycles after each overflow. */
    ADMUX = _BV(REFS0) | adc_channels[0];
    ADCSRB = _BV(ADTS2) | _BV(ADTS1);
    ADCSRA = _BV(ADEN) | _BV(ADATE) | _BV(ADIE) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);
    DIDR0 = _BV(ADC0D) | _BV(ADC1D) | _BV(ADC2D) | _BV(ADC3D);

    /* USART0: 250000 baud with U2X (UBRR = 7, exact), 8N1, RX interrupt. */
    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)(F_CPU / (8UL * AEROPEND_BAUD) - 1);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);

    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
}

void loop(void)
{
    while (rx_tail != rx_head) {
        uint8_t byte = rx_buffer[rx_tail];
        rx_tail = (uint8_t)((rx_tail + 1) % RX_SIZE);
        receive_byte(byte);
    }
    if (sample_ready)
        send_sample();
    if (status_due)
        send_status();
    /* Sleep until the next interrupt unless one already left work for us. */
    cli();
    if (!sample_ready && !status_due && rx_tail == rx_head) {
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
    }
    sei();
}

#ifndef ARDUINO
int main(void)
{
    setup();
    for (;;)
        loop();
}
#endif

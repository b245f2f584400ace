/*
 * aeropend serial protocol, device side. The host side is aeropend_core/rig/protocol.py; its module docstring is
 * the reference description of the format and both are tested against each other (tests/test_firmware_sim.py).
 *
 * Every message on the wire: 0x00 COBS(payload + CRC16_LE(payload)) 0x00
 * CRC-16/CCITT-FALSE: polynomial 0x1021, init 0xFFFF, not reflected, no final XOR (check "123456789" -> 0x29B1).
 * Fields little-endian.
 */
#ifndef AEROPEND_PROTOCOL_H
#define AEROPEND_PROTOCOL_H

#include <stdint.h>

#define AP_PROTOCOL_VERSION 2

/* Message types. */
#define AP_MSG_SAMPLE 0x01          /* device -> host, 14-byte payload */
#define AP_MSG_STATUS 0x02          /* device -> host, 18-byte payload */
#define AP_CMD_SET_DUTY 0x10        /* host -> device: u16 duty fraction * 65535 */
#define AP_CMD_SET_MAX_DUTY 0x11    /* host -> device: u16 max duty fraction * 65535 */
#define AP_CMD_SET_WATCHDOG 0x12    /* host -> device: u16 timeout in ms (10..60000) */
#define AP_CMD_REQUEST_STATUS 0x13  /* host -> device: u16 ignored */
/* Version 2: the closed loop (aeropend_control.h). The four commands below are each answered by an ACK. */
#define AP_MSG_ACK 0x03                 /* device -> host: u8 command, u8 index, u8 result, f32 value (8 bytes) */
#define AP_MSG_CONTROL_SAMPLE 0x04      /* device -> host: SAMPLE's fields + f32 reference, feedforward,
                                           unsaturated, integral (30 bytes), every sample in closed loop */
#define AP_CMD_SET_CONTROL_COEFFICIENT 0x14 /* host -> device: u8 index 0..13, f32 value (6 bytes) */
#define AP_CMD_SET_REFERENCE 0x15           /* host -> device: f32 reference rad, f32 feedforward duty (9 bytes) */
#define AP_CMD_SET_CONTROL_MODE 0x16        /* host -> device: u16 0 open loop, 1 closed loop (3 bytes) */
#define AP_CMD_SET_ANGLE_CALIBRATION 0x17   /* host -> device: f32 zero counts, f32 rad per count (9 bytes) */

/* result of ACK */
#define AP_ACK_OK 0
#define AP_ACK_OUT_OF_RANGE 1
#define AP_ACK_UNKNOWN_INDEX 2
#define AP_ACK_REFUSED 3

#define AP_MODE_OPEN_LOOP 0
#define AP_MODE_CLOSED_LOOP 1

/* flags byte of SAMPLE and STATUS. */
#define AP_FLAG_WATCHDOG_TRIPPED 0x01
#define AP_FLAG_DUTY_CLAMPED 0x02
#define AP_FLAG_SAMPLES_DROPPED 0x04
#define AP_FLAG_BOOT 0x08
#define AP_FLAG_LAW_TRIPPED 0x10 /* closed loop: angle outside [ANGLE_MIN, ANGLE_MAX], duty 0, latched */
#define AP_FLAG_CLOSED_LOOP 0x20

/* pwm_mode of STATUS. */
#define AP_PWM_PHASE_CORRECT 0
#define AP_PWM_FAST 1

#define AP_SAMPLE_PAYLOAD 14
#define AP_STATUS_PAYLOAD 18
#define AP_ACK_PAYLOAD 8
#define AP_CONTROL_SAMPLE_PAYLOAD 30
#define AP_COMMAND_PAYLOAD 3
#define AP_COEFFICIENT_PAYLOAD 6
#define AP_TWO_FLOAT_PAYLOAD 9
#define AP_MAX_PAYLOAD AP_CONTROL_SAMPLE_PAYLOAD
/* Largest encoded message: payload + CRC + COBS overhead + two delimiters. */
#define AP_MAX_WIRE (AP_MAX_PAYLOAD + 2 + 1 + 2)
/* Largest encoded command between its delimiters: payload + CRC + COBS overhead. */
#define AP_MAX_COMMAND_CHUNK (AP_TWO_FLOAT_PAYLOAD + 2 + 1)

static inline uint16_t ap_crc16_update(uint16_t crc, uint8_t data)
{
    /* Same recurrence as avr-libc's _crc_xmodem_update (poly 0x1021, MSB first). */
    crc ^= (uint16_t)data << 8;
    for (uint8_t bit = 0; bit < 8; bit++)
        crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    return crc;
}

static inline uint16_t ap_crc16(const uint8_t *data, uint8_t length)
{
    uint16_t crc = 0xFFFF;
    for (uint8_t i = 0; i < length; i++)
        crc = ap_crc16_update(crc, data[i]);
    return crc;
}

/*
 * Frame `payload` (length <= AP_MAX_PAYLOAD) into `out`: 0x00, COBS(payload + CRC), 0x00. Returns the number of bytes
 * written (length + 5). `out` must hold length + 5 bytes.
 */
static inline uint8_t ap_frame(const uint8_t *payload, uint8_t length, uint8_t *out)
{
    uint8_t raw[AP_MAX_PAYLOAD + 2];
    uint16_t crc = ap_crc16(payload, length);
    for (uint8_t i = 0; i < length; i++)
        raw[i] = payload[i];
    raw[length] = (uint8_t)(crc & 0xFF);
    raw[length + 1] = (uint8_t)(crc >> 8);
    uint8_t n = length + 2;
    out[0] = 0x00;
    uint8_t code_index = 1, write = 2, code = 1;
    for (uint8_t i = 0; i < n; i++) {
        if (raw[i] == 0) {
            out[code_index] = code;
            code_index = write++;
            code = 1;
        } else {
            out[write++] = raw[i];
            code++;
        }
    }
    out[code_index] = code;
    out[write++] = 0x00;
    return write;
}

/*
 * Decode one COBS chunk (delimiters removed) in place. Returns the decoded length or -1 when the chunk is not
 * valid COBS.
 */
static inline int16_t ap_cobs_decode(uint8_t *buffer, uint8_t length)
{
    uint8_t read = 0, write = 0;
    while (read < length) {
        uint8_t code = buffer[read];
        if (code == 0 || (uint16_t)read + code > length)
            return -1;
        read++;
        for (uint8_t i = 1; i < code; i++)
            buffer[write++] = buffer[read++];
        if (code != 0xFF && read < length)
            buffer[write++] = 0;
    }
    return write;
}

static inline void ap_put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static inline void ap_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}

/* float32 fields: both the AVR and the hosts are little-endian IEEE single. */
static inline void ap_put_f32(uint8_t *p, float v)
{
    union { float f; uint32_t u; } bits;
    bits.f = v;
    ap_put_u32(p, bits.u);
}
static inline float ap_get_f32(const uint8_t *p)
{
    union { float f; uint32_t u; } bits;
    bits.u = (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
    return bits.f;
}
/* Not infinite, not NaN: the exponent is not all ones (no libm). */
static inline uint8_t ap_f32_finite(float v)
{
    union { float f; uint32_t u; } bits;
    bits.f = v;
    return ((bits.u >> 23) & 0xFF) != 0xFF;
}

#endif /* AEROPEND_PROTOCOL_H */

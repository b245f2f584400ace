/*
 * Host-side check of firmware/aeropend/aeropend_protocol.h against aeropend_core/rig/protocol.py
 * (tests/test_firmware_sim.py). Reads lines from stdin, writes one answer line each:
 *   "frame HEX"  -> HEX of ap_frame(payload)          (device -> host framing, CRC and COBS)
 *   "decode HEX" -> HEX of ap_cobs_decode(chunk) or "invalid"
 *   "crc HEX"    -> the CRC-16 as 4 hex digits
 */
#include <stdio.h>
#include <string.h>

#include "../aeropend/aeropend_protocol.h"

static int parse_hex(const char *text, uint8_t *out, int capacity)
{
    int n = 0;
    unsigned value;
    while (text[0] && text[1] && text[0] != '\n' && n < capacity && sscanf(text, "%2x", &value) == 1) {
        out[n++] = (uint8_t)value;
        text += 2;
    }
    return n;
}

static void print_hex(const uint8_t *data, int length)
{
    for (int i = 0; i < length; i++)
        printf("%02x", data[i]);
    printf("\n");
}

int main(void)
{
    char line[1024];
    uint8_t data[256], out[300];
    while (fgets(line, sizeof(line), stdin)) {
        if (!strncmp(line, "frame ", 6)) {
            int n = parse_hex(line + 6, data, AP_MAX_PAYLOAD);
            print_hex(out, ap_frame(data, (uint8_t)n, out));
        } else if (!strncmp(line, "decode ", 7)) {
            int n = parse_hex(line + 7, data, 255);
            int16_t m = ap_cobs_decode(data, (uint8_t)n);
            if (m < 0)
                printf("invalid\n");
            else
                print_hex(data, m);
        } else if (!strncmp(line, "crc ", 4)) {
            int n = parse_hex(line + 4, data, 255);
            printf("%04x\n", ap_crc16(data, (uint8_t)n));
        } else {
            printf("?\n");
        }
        fflush(stdout);
    }
    return 0;
}

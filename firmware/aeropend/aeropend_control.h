/*
 * The closed loop's controller law, device side: a line-by-line single-precision mirror of law_step() in
 * aeropend_core/control/law.py (the reference; its module docstring states the law). Plain C, no libm: builds with
 * avr-gcc (where float and double are both 32-bit IEEE single) and with a host C compiler. Checked against the
 * Python law on shared vectors (aeropend_core/testing/law_vectors.py; tests/test_firmware_sim.py runs the host
 * build and the avr-gcc build in simavr on the same vectors).
 *
 * Coefficients c[14] (PidGains.coefficients(Ts) on the host, sent one by one with SET_CONTROL_COEFFICIENT):
 *   P, I_TS, D_POLE, D_GAIN, I_MIN, I_MAX, U_MIN, U_MAX, AW_CODE, AW_GAIN, FF_GAIN, ANGLE_MIN, ANGLE_MAX,
 *   SETPOINT_WEIGHT (b: the proportional term is p (b r - y); 1 = the plain PID on the error).
 * State s[6], changed in place: INTEGRAL, DERIVATIVE, PREVIOUS_ANGLE, PRIMED, TRIPPED, UNSATURATED.
 *
 * Cost on the ATmega2560 (-Os, avr-libc soft float), measured in simavr on the shared vectors (law_vectors.c 'T'
 * records): median ~2,800 CPU cycles, at most ~3,500 (0.22 ms, 11 % of the 2.04 ms period = 32,640 cycles; with the
 * setpoint weight, session 19: before it ~2,550 and ~3,150).
 */
#ifndef AEROPEND_CONTROL_H
#define AEROPEND_CONTROL_H

#define AP_C_P 0
#define AP_C_I_TS 1
#define AP_C_D_POLE 2
#define AP_C_D_GAIN 3
#define AP_C_I_MIN 4
#define AP_C_I_MAX 5
#define AP_C_U_MIN 6
#define AP_C_U_MAX 7
#define AP_C_AW_CODE 8
#define AP_C_AW_GAIN 9
#define AP_C_FF_GAIN 10
#define AP_C_ANGLE_MIN 11
#define AP_C_ANGLE_MAX 12
#define AP_C_SETPOINT_WEIGHT 13
#define AP_N_COEFFICIENTS 14

#define AP_S_INTEGRAL 0
#define AP_S_DERIVATIVE 1
#define AP_S_PREVIOUS_ANGLE 2
#define AP_S_PRIMED 3
#define AP_S_TRIPPED 4
#define AP_S_UNSATURATED 5
#define AP_N_STATE 6

/* Anti-windup codes (c[AP_C_AW_CODE]), as law.ANTIWINDUP. */
#define AP_AW_NONE 0
#define AP_AW_BACK_CALCULATION 1
#define AP_AW_CONDITIONAL_INTEGRATION 2

/* One sample of the law: the duty [fraction] to apply from this sample; `s` is updated in place. */
static inline float ap_law_step(const float c[14], float s[6], float reference, float feedforward, float angle)
{
    if (s[4] != 0.0f)
        return 0.0f;
    if (angle < c[11] || angle > c[12]) {
        s[4] = 1.0f;
        s[5] = 0.0f;
        return 0.0f;
    }
    float error = reference - angle;
    if (s[3] == 0.0f) {
        s[1] = 0.0f;
        s[3] = 1.0f;
    } else {
        s[1] = c[2] * s[1] - c[3] * (angle - s[2]);
    }
    s[2] = angle;
    float unsaturated = c[10] * feedforward + c[0] * (c[13] * reference - angle) + s[0] + s[1];
    float duty = unsaturated;
    if (duty > c[7])
        duty = c[7];
    if (duty < c[6])
        duty = c[6];
    float integral = s[0];
    if (c[8] == 1.0f) {
        integral = integral + c[1] * error + c[9] * (duty - unsaturated);
    } else if (c[8] == 2.0f) {
        if (!((unsaturated > c[7] && error > 0.0f) || (unsaturated < c[6] && error < 0.0f)))
            integral = integral + c[1] * error;
    } else {
        integral = integral + c[1] * error;
    }
    if (integral > c[5])
        integral = c[5];
    if (integral < c[4])
        integral = c[4];
    s[0] = integral;
    s[5] = unsaturated;
    return duty;
}

#endif /* AEROPEND_CONTROL_H */

"""Write the sample logs of samples/: two logs as other rigs write them, made by the simulator (not measured).

  rig_log.csv            the source paper's kind of logger (read with config/profiles/arduino_logger.yaml): a PC
                         date-time per line, the duty as the 0..255 register, the current as A0 ADC counts read
                         inside the PWM pulse, the angle as AS5040 counts; one line every 22 PWM periods (22.27 Hz)
  rig_log_semicolon.csv  a ';'-separated log (read with samples/rig_log_semicolon.yaml): the logger's millis(), the
                         duty in percent, the period-average current as ADC counts from a mid-rail sensor (512 at
                         0 A), the angle in degrees; one line
                         every 2 PWM periods (245 Hz)

Both: the default simulated rig, no hidden effect, 25 s (aeropend_core.testing.foreign_logs.generate). Run from
the repository's root: .venv/bin/python samples/make_samples.py
"""
from __future__ import annotations

from pathlib import Path

import yaml

from aeropend_core.testing.foreign_logs import ForeignLogSpec, generate

HERE = Path(__file__).resolve().parent


def main() -> None:
    paper = generate(ForeignLogSpec(seed=7, duration=25.0, angle_zero_counts=0,
                                    column_names={'time': 'time', 'current': 'current', 'angle': 'angle',
                                                  'duty': 'pwm'}))
    (HERE / 'rig_log.csv').write_text(paper.text, encoding='utf-8')
    semicolon = generate(ForeignLogSpec(seed=8, duration=25.0, periods_per_line=2, stamps='device_ms',
                                        duty='percent', angle='degrees', current='average', current_offset_counts=512,
                                        column_names={'time': 'millis', 'current': 'current_counts',
                                                      'angle': 'theta_deg', 'duty': 'duty_pct'}))
    (HERE / 'rig_log_semicolon.csv').write_text(semicolon.text.replace(',', ';'), encoding='utf-8')
    profile = dict(semicolon.profile, name='sample ;-separated logger (millis, duty %, current counts, degrees)',
                   delimiter=';')
    profile['clock'] = {k: v for k, v in profile['clock'].items() if k != 'rate'}
    text = ('# Profile of samples/rig_log_semicolon.csv (written by samples/make_samples.py from the simulator)\n'
            + yaml.safe_dump(profile, sort_keys=False, default_flow_style=None))
    (HERE / 'rig_log_semicolon.yaml').write_text(text, encoding='utf-8')


if __name__ == '__main__':
    main()

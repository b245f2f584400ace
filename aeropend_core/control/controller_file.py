"""The controller file ``aeropend control design`` writes and ``aeropend run --controller`` reads (YAML, SI units).

::

    aeropend_controller: 1
    gains: {p: 0.42, i: 0.9, d: 0.031, derivative_filter_time: 0.02, ...}   # PidGains (setpoint_weight: 1 if absent)
    template: {settling: 2.0, overshoot: 10.0, error: 5.0, duty: 0.8}     # what it was designed for
    model:                                                                 # what it was designed on
      source: nominal                  # or the diagnosis/identify JSON it came from
      parameters: {gravity_stiffness: 131.75, ...}                        # RigParameters, SI
      effects: {EFFECT: {PARAMETER: VALUE}}                              # the catalog's names
      sha256: ...                      # of parameters + effects
    design: {...}                      # operating point, predicted metrics (for the reader; not read back)
    sha256: ...                        # of gains + model: the bag's metadata names the controller by it

The feedforward of the law is the static duty of *this* model (:mod:`aeropend_core.control.feedforward`).
"""
from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields

from aeropend_core.control.law import PidGains
from aeropend_core.control.metrics import Template
from aeropend_core.errors import AeropendError
from aeropend_core.model.effects import resolve_effects
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, RigParameters

FORMAT_VERSION = 1


def model_hash(parameters: RigParameters, effects: Mapping[str, Mapping[str, float]]) -> str:
    """sha256 of a model's parameters and effects (canonical JSON)."""
    content = {'parameters': parameters.as_dict(), 'effects': {name: dict(values) for name, values in
                                                               sorted(effects.items())}}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


@dataclass(frozen=True)
class Controller:
    """A controller and the model it was designed on."""

    gains: PidGains
    parameters: RigParameters = DEFAULT_PARAMETERS
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    template: Template | None = None
    model_source: str = 'nominal'
    design: Mapping = field(default_factory=dict)

    @property
    def schedule(self):
        """The reference schedule the gains were designed on (:class:`ReferenceSchedule`), None if not stored."""
        stored = self.design.get('schedule') if isinstance(self.design, Mapping) else None
        if not isinstance(stored, Mapping):
            return None
        from aeropend_core.control.reference import ReferenceSchedule
        dither = stored.get('dither') or {}
        return ReferenceSchedule.from_mapping({'start_angle': stored.get('start_angle', 0.0),
                                               'start_hold': stored.get('start_hold', 2.0),
                                               'steps': stored.get('steps'),
                                               'dither': dither}, 'the controller file\'s design schedule')

    @property
    def model_sha256(self) -> str:
        return model_hash(self.parameters, self.effects)

    @property
    def sha256(self) -> str:
        """Hash of the gains and the model (what makes the loop behave as it does); ``setpoint_weight`` 1 is left out
        (:meth:`PidGains.hashed_dict`), so files written before it existed (which load with b = 1) keep theirs."""
        content = {'gains': self.gains.hashed_dict(), 'model': self.model_sha256}
        return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()

    def to_dict(self) -> dict:
        return {'aeropend_controller': FORMAT_VERSION,
                'gains': self.gains.as_dict(),
                'template': self.template.as_dict() if self.template else None,
                'model': {'source': self.model_source, 'parameters': self.parameters.as_dict(),
                          'effects': {name: dict(values) for name, values in self.effects.items()},
                          'sha256': self.model_sha256},
                'design': dict(self.design),
                'sha256': self.sha256}

    def write(self, path: str | os.PathLike) -> None:
        """Write the YAML file (atomically)."""
        import yaml

        from aeropend_core.io.atomic import atomic_write
        text = ('# aeropend controller: gains of the law (docs/control.md) and the model they were designed on; '
                'SI units, duty as a fraction 0..1\n' + yaml.safe_dump(_plain(self.to_dict()), sort_keys=False))
        atomic_write(path, lambda handle: handle.write(text))

    @classmethod
    def from_dict(cls, data, source: str = 'controller file') -> Controller:
        if not isinstance(data, Mapping) or 'gains' not in data:
            raise AeropendError(f'{source}: not an aeropend controller file (no "gains" section); write one with '
                                '`aeropend control design -o gains.yaml`')
        version = data.get('aeropend_controller', FORMAT_VERSION)
        if version != FORMAT_VERSION:
            raise AeropendError(f'{source}: controller file version {version!r}; this aeropend reads version '
                                f'{FORMAT_VERSION}')
        if not isinstance(data['gains'], Mapping):
            raise AeropendError(f'{source}: "gains" must be a mapping of p, i, d, ...')
        gains = PidGains.from_mapping(data['gains'], source)
        model = data.get('model') or {}
        if not isinstance(model, Mapping):
            raise AeropendError(f'{source}: "model" must be a mapping')
        raw_parameters = model.get('parameters') or {}
        known = {item.name for item in fields(RigParameters)}
        unknown = sorted(set(raw_parameters) - known) if isinstance(raw_parameters, Mapping) else ['(not a mapping)']
        if unknown:
            raise AeropendError(f'{source}: model parameters {", ".join(map(str, unknown))} are not rig parameters')
        try:
            parameters = DEFAULT_PARAMETERS.replace(**{name: float(value) for name, value in raw_parameters.items()})
            effects = resolve_effects(model.get('effects') or {})
        except (TypeError, ValueError) as error:
            raise AeropendError(f'{source}: model: {error}') from None
        template = data.get('template')
        template = Template(**{name: template.get(name) for name in Template.ITEMS}) if isinstance(
            template, Mapping) else None
        controller = cls(gains, parameters, effects, template, str(model.get('source', 'nominal')),
                         data.get('design') or {})
        stated = data.get('sha256')
        if stated is not None and stated != controller.sha256:
            raise AeropendError(f'{source}: its sha256 does not match its gains and model (edited by hand?); '
                                'delete the sha256 line to accept the edit, or design again')
        return controller

    @classmethod
    def load(cls, path: str | os.PathLike) -> Controller:
        """Read a controller file; a clear AeropendError for every problem."""
        import yaml

        from aeropend_core.io.inputs import load_yaml
        try:
            data = load_yaml(path, 'controller file')
        except yaml.YAMLError as error:
            mark = getattr(error, 'problem_mark', None)
            where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark is not None else ''
            problem = getattr(error, 'problem', None) or 'a syntax error'
            raise AeropendError(f'controller file {path}: not valid YAML ({problem}{where}); write it with '
                                '`aeropend control design -o gains.yaml`') from None
        return cls.from_dict(data, f'controller file {path}')


def _plain(value):
    """numpy scalars and tuples as plain YAML types."""
    if isinstance(value, Mapping):
        return {str(key): _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if hasattr(value, 'item') and callable(value.item):
        return value.item()
    return value

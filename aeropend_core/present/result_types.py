"""What present/ reads of a diagnosis, as a structural type (:class:`DiagnosisLike`, a ``typing.Protocol``).

:class:`aeropend_core.diagnosis.diagnose.Diagnosis` presents itself by importing present/ when one of its methods
runs (``summary()``, ``as_text()``, ``as_html()``, ``to_dict()``), so present/ does not import that class, not even
for annotations: it annotates with this protocol, which the class meets, and the import graph points one way
(docs/architecture.md). The types of the attributes come from modules below both.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:       # annotations only; none of these modules imports present/ or the diagnosis above them
    from aeropend_core.diagnosis.candidates import Candidate
    from aeropend_core.diagnosis.compare import Comparison, PreparedRecord
    from aeropend_core.diagnosis.discovery import Discovery
    from aeropend_core.diagnosis.motor_discovery import MotorDiscovery
    from aeropend_core.diagnosis.remainder import Remainder
    from aeropend_core.diagnosis.stages import Found, VerdictFacts
    from aeropend_core.diagnosis.state_map import StateMap
    from aeropend_core.diagnosis.verdicts import Verdict
    from aeropend_core.identify.plausibility import FreeOscillation


class DiagnosisLike(Protocol):
    """The attributes and methods of a diagnosis that present/ reads. Angles in rad, parameters SI; each is described
    on :class:`aeropend_core.diagnosis.diagnose.Diagnosis`."""

    effects: tuple[str, ...]
    current: Comparison
    candidates: list[Candidate]
    missing_effect: str | None
    verdict: Verdict
    facts: VerdictFacts
    notes: list[str]
    before: Comparison | None
    residual_structure: list[dict[str, float | str]]
    prepared: PreparedRecord | None
    seconds: float
    found: list[Found]
    selected: Comparison | None
    drift: list[dict]
    fixed: dict[str, float]
    fixed_from: dict[str, str]
    parameter_warnings: dict[str, str]
    parameter_doubts: dict[str, str]
    independent: FreeOscillation | None
    discovery: Discovery | None
    motor_discovery: MotorDiscovery | None
    state_map: StateMap | None
    state_map_selected: StateMap | None
    remainder: Remainder | None

    @property
    def missing_effects(self) -> list[str]: ...

    @property
    def findings(self) -> tuple: ...

    @property
    def noise_rms(self) -> float: ...

    @property
    def final(self) -> Comparison: ...

    def reported_parameters(self, comparison: Comparison) -> dict[str, float]: ...

    def reported_errors(self, comparison: Comparison, values: bool = False) -> dict[str, float]: ...

    def numbers_dict(self) -> dict: ...

"""The settings of an impact test: one vocabulary for the API, the rig file, the CLI and the session.

:class:`ImpactSettings` is what :class:`dimacq.services.acquisition.session.ImpactSession` runs with (every
value concrete). :class:`ImpactOverrides` is the same user-facing fields, each optional: what an
API request (``POST /api/acquisitions``) or a rig file's ``[acquisition]`` table gives, ``None``
meaning "not given here". :meth:`ImpactSettings.layered` applies overrides in order of priority —
built-in defaults < the rig file < the request < what the rig imposes (e.g. how far ahead the
simulated lab can be struck). Names, units and bounds of every field are written once, in the
``Annotated`` aliases below.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["Estimator", "ImpactOverrides", "ImpactSettings"]

Estimator = Literal["H1", "H2", "Hv"]
ESTIMATOR_DOC = "FRF estimator: 'H1', 'H2' or 'Hv'"

RecordSamples = Annotated[
    int, Field(ge=64, le=1_048_576, description="samples per average (the FFT length), 64..2^20")
]
PretriggerSamples = Annotated[
    int, Field(ge=0, le=65536, description="samples kept before the trigger, 0..65536")
]
TriggerLevelN = Annotated[
    float,
    Field(
        ge=0.001,
        le=1e6,
        allow_inf_nan=False,
        description="hammer force that triggers a record, N (0.001..1e6)",
    ),
]
AveragesPerInput = Annotated[
    int, Field(ge=1, le=100, description="accepted averages wanted per input, 1..100")
]
MinAverages = Annotated[
    int,
    Field(
        ge=1,
        le=100,
        description="fewest accepted averages per input, 1..100 (capped at averages_per_input); "
        "an input left below it after the strike budget is incomplete and gets no FRF",
    ),
]
ForceWindowSamples = Annotated[
    int, Field(ge=1, le=1_048_576, description="force window length after the trigger, samples")
]
ExponentialTauS = Annotated[
    float,
    Field(
        ge=1e-6,
        le=1e4,
        allow_inf_nan=False,
        description="exponential window time constant from the trigger, s",
    ),
]


def _doc(alias: Any) -> Any:
    """A ``None`` default carrying the description of ``alias`` (so that an optional field is
    documented like its concrete twin, e.g. in the API schema)."""
    return Field(default=None, description=alias.__metadata__[0].description)


class ImpactOverrides(BaseModel):
    """Impact-test settings given by a request or a rig file (None: not given here)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    record_samples: RecordSamples | None = _doc(RecordSamples)
    pretrigger_samples: PretriggerSamples | None = _doc(PretriggerSamples)
    trigger_level_n: TriggerLevelN | None = _doc(TriggerLevelN)
    averages_per_input: AveragesPerInput | None = _doc(AveragesPerInput)
    min_averages: MinAverages | None = _doc(MinAverages)
    force_window_samples: ForceWindowSamples | None = _doc(ForceWindowSamples)
    exponential_tau_s: ExponentialTauS | None = _doc(ExponentialTauS)
    estimator: Estimator | None = Field(default=None, description=ESTIMATOR_DOC)

    def given(self) -> dict[str, Any]:
        """The values given (not None)."""
        return {k: v for k, v in self.model_dump().items() if v is not None}

    @model_validator(mode="after")
    def _consistent(self) -> ImpactOverrides:
        _check_pair(self.pretrigger_samples, self.record_samples)
        return self


def _check_pair(pretrigger: int | None, record: int | None) -> None:
    """Settings that must agree with each other (where both are given)."""
    if pretrigger is not None and record is not None and not pretrigger < record:
        raise ValueError(
            f"pretrigger_samples {pretrigger} must be below record_samples {record}: "
            "lower pretrigger_samples or raise record_samples"
        )


class ImpactSettings(BaseModel):
    """Settings of an impact test, every value concrete.

    Attributes
    ----------
    record_samples, pretrigger_samples, trigger_level_n, averages_per_input, min_averages,
    force_window_samples, exponential_tau_s, estimator
        As in :class:`ImpactOverrides` (``force_window_samples`` / ``exponential_tau_s`` None:
        no such window). ``min_averages`` (capped at ``averages_per_input``: a test asking one
        average gets it, with its coherence NaN): an input with fewer accepted averages after
        the strike budget is incomplete (no FRF). The API and ``dimacq acquire`` default it to
        the service's ``min_averages`` setting (3).
    block_samples : int
        DAQ read size, samples.
    max_attempts_factor : int
        At most ``factor × averages_per_input`` strikes per input.
    double_hit_threshold : float
        Fraction of the peak force that counts as a second pulse.
    hit_delay_samples : int
        How far ahead the operator is asked to strike (simulation: exactly then).
    trigger_timeout_samples : int
        Samples to wait for a strike before giving up.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    record_samples: RecordSamples = 2048
    pretrigger_samples: PretriggerSamples = 32
    trigger_level_n: TriggerLevelN = 5.0
    averages_per_input: AveragesPerInput = 5
    min_averages: MinAverages = 2
    force_window_samples: ForceWindowSamples | None = _doc(ForceWindowSamples)
    exponential_tau_s: ExponentialTauS | None = _doc(ExponentialTauS)
    estimator: Estimator = Field(default="H1", description=ESTIMATOR_DOC)
    block_samples: int = Field(default=512, ge=1)
    max_attempts_factor: int = Field(default=3, ge=1)
    double_hit_threshold: float = Field(default=0.1, gt=0, lt=1)
    hit_delay_samples: int = Field(default=64, ge=0)
    trigger_timeout_samples: int = Field(default=200_000, ge=1)

    @model_validator(mode="after")
    def _consistent(self) -> ImpactSettings:
        _check_pair(self.pretrigger_samples, self.record_samples)
        return self

    @classmethod
    def layered(cls, *layers: ImpactOverrides | Mapping[str, Any] | None) -> ImpactSettings:
        """Built-in defaults overridden by each layer in turn (later wins; None values and
        None layers are skipped; mappings may hold keys that are not settings, e.g. a request's
        ``setup_id``, which are ignored)."""
        values: dict[str, Any] = {}
        for layer in layers:
            if layer is None:
                continue
            items = layer.given() if isinstance(layer, ImpactOverrides) else dict(layer)
            values.update(
                {k: v for k, v in items.items() if v is not None and k in cls.model_fields}
            )
        return cls.model_validate(values)

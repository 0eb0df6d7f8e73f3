"""FRF data: a complex array ``H`` of shape ``(n_lines, n_outputs, n_inputs)`` with its identity.

Units (SI): accelerometer outputs are accelerance, (m/s²)/N; load cell outputs are reaction
transmissibility, N/N for forces (directions 1–3) and N·m/N for moments (directions 4–6), in the
cell's local system. :func:`to_accelerance` converts from g, mm and from displacement or velocity
FRFs: with ``x(ω) = X e^{iωt}``, ``ẋ = iω x`` and ``ẍ = −ω² x``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError
from dimacq.model.setup import direction_label

__all__ = [
    "MAX_FREQUENCY_HZ",
    "MAX_FRF_MAGNITUDE",
    "STANDARD_GRAVITY",
    "Channel",
    "FrfData",
    "to_accelerance",
]

#: Standard gravity, m/s² per g.
STANDARD_GRAVITY = 9.80665
#: The highest frequency line of an FRF set, Hz (half the highest DAQ sample rate a rig takes).
MAX_FREQUENCY_HZ = 5e6
#: The largest |H| of an FRF (SI): far above any accelerance or transmissibility, and small
#: enough that products and sums of squares in the solver stay finite.
MAX_FRF_MAGNITUDE = 1e100

OutputKind = Literal["acceleration", "reaction"]


@dataclass(frozen=True)
class Channel:
    """A measurement degree of freedom: node and UFF direction (±1..±6)."""

    node: int
    direction: int

    @property
    def name(self) -> str:
        return f"{self.node}{direction_label(self.direction)}"

    def as_dict(self) -> dict[str, int]:
        return {"node": self.node, "direction": self.direction}


@dataclass(frozen=True, eq=False)
class FrfData:
    """FRFs of one test.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
        Strictly increasing frequency axis, Hz.
    H : ndarray, shape (n_lines, n_outputs, n_inputs), complex
        FRFs in SI units (see module docstring).
    outputs : tuple of Channel, length n_outputs
    output_kinds : tuple of {"acceleration", "reaction"}, length n_outputs
    inputs : tuple of Channel, length n_inputs
    coherence : ndarray, shape (n_lines, n_outputs, n_inputs), optional
    """

    frequencies_hz: NDArray[np.float64]
    H: NDArray[np.complex128]
    outputs: tuple[Channel, ...]
    output_kinds: tuple[OutputKind, ...]
    inputs: tuple[Channel, ...]
    coherence: NDArray[np.float64] | None = None
    meta: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        f = np.asarray(self.frequencies_hz, dtype=float)
        h = np.asarray(self.H)
        object.__setattr__(self, "frequencies_hz", f)
        object.__setattr__(self, "H", h.astype(complex, copy=False))
        if f.ndim != 1 or f.size == 0:
            raise DataError("frequencies_hz must be a non-empty 1-D array of frequency lines in Hz")
        if h.ndim != 3 or h.shape[0] != f.size:
            raise DataError(
                f"H has shape {h.shape}; it must be (n_lines={f.size}, n_outputs, n_inputs)"
            )
        if len(self.outputs) != h.shape[1] or len(self.output_kinds) != h.shape[1]:
            raise DataError(
                f"H has {h.shape[1]} outputs but {len(self.outputs)} output channels and "
                f"{len(self.output_kinds)} output kinds are given; give one of each per output"
            )
        if len(self.inputs) != h.shape[2]:
            raise DataError(
                f"H has {h.shape[2]} inputs but {len(self.inputs)} input channels are given"
            )
        if not np.all(np.isfinite(f)) or np.any(np.diff(f) <= 0):
            raise DataError("frequencies_hz must be finite and strictly increasing")
        if f[0] < 0 or f[-1] > MAX_FREQUENCY_HZ:
            raise DataError(
                f"frequencies_hz runs from {f[0]:g} to {f[-1]:g} Hz; give lines within "
                f"0..{MAX_FREQUENCY_HZ:g} Hz (check the file's abscissa start and increment)"
            )
        bad = ~np.isfinite(h)
        with np.errstate(invalid="ignore"):
            bad |= np.abs(h) > MAX_FRF_MAGNITUDE
        if bad.any():
            line, out, inp = (int(i[0]) for i in np.nonzero(bad))
            raise DataError(
                f"FRF {self.outputs[out].name}/{self.inputs[inp].name} has NaN or inf at "
                f"{f[line]:g} Hz (or a magnitude above {MAX_FRF_MAGNITUDE:g}; "
                f"{int(bad.sum())} values in all); remove or re-measure that record"
            )
        for kind in self.output_kinds:
            if kind not in ("acceleration", "reaction"):
                raise DataError(
                    f"output kind {kind!r} is unknown; use 'acceleration' or 'reaction'"
                )
        if len(set(self.outputs)) != len(self.outputs):
            raise DataError("an output channel appears twice; give each node/direction once")
        if len(set(self.inputs)) != len(self.inputs):
            raise DataError("an input channel appears twice; give each node/direction once")

    @property
    def n_lines(self) -> int:
        return int(self.H.shape[0])

    def output_index(self, kind: OutputKind) -> NDArray[np.intp]:
        """Indices of the outputs of one kind."""
        return np.array([i for i, k in enumerate(self.output_kinds) if k == kind], dtype=np.intp)

    def band(self, lo_hz: float, hi_hz: float) -> FrfData:
        """The lines with ``lo_hz <= f <= hi_hz``."""
        sel = (self.frequencies_hz >= lo_hz) & (self.frequencies_hz <= hi_hz)
        if not sel.any():
            raise DataError(
                f"band {lo_hz:g}–{hi_hz:g} Hz holds no line (data span "
                f"{self.frequencies_hz[0]:g}–{self.frequencies_hz[-1]:g} Hz); choose a band inside it"
            )
        idx = np.flatnonzero(sel)
        # one run of lines (a band of increasing frequencies): views of it, not copies
        key: slice | NDArray[np.bool_] = (
            slice(int(idx[0]), int(idx[-1]) + 1) if idx[-1] - idx[0] + 1 == idx.size else sel
        )
        return self.replace(
            frequencies_hz=self.frequencies_hz[key],
            H=self.H[key],
            coherence=None if self.coherence is None else self.coherence[key],
        )

    def select(
        self,
        outputs: NDArray[np.intp] | None = None,
        inputs: NDArray[np.intp] | None = None,
    ) -> FrfData:
        """A copy restricted to the given output and input indices."""
        oi = np.arange(self.H.shape[1]) if outputs is None else np.asarray(outputs, dtype=np.intp)
        ii = np.arange(self.H.shape[2]) if inputs is None else np.asarray(inputs, dtype=np.intp)
        return self.replace(
            H=self.H[:, oi][:, :, ii],
            outputs=tuple(self.outputs[i] for i in oi),
            output_kinds=tuple(self.output_kinds[i] for i in oi),
            inputs=tuple(self.inputs[i] for i in ii),
            coherence=None if self.coherence is None else self.coherence[:, oi][:, :, ii],
        )

    def replace(self, **changes: object) -> FrfData:
        fields = {
            "frequencies_hz": self.frequencies_hz,
            "H": self.H,
            "outputs": self.outputs,
            "output_kinds": self.output_kinds,
            "inputs": self.inputs,
            "coherence": self.coherence,
            "meta": dict(self.meta),
        }
        fields.update(changes)
        return FrfData(**fields)  # type: ignore[arg-type]

    def scaled(
        self, gamma: float, kinds: tuple[OutputKind, ...] = ("acceleration", "reaction")
    ) -> FrfData:
        """FRFs of the given output kinds multiplied by ``gamma``."""
        scale = np.array([gamma if k in kinds else 1.0 for k in self.output_kinds])
        return self.replace(H=self.H * scale[None, :, None])


def to_accelerance(
    H: NDArray[np.complexfloating],
    frequencies_hz: NDArray[np.floating],
    *,
    quantity: Literal["acceleration", "velocity", "displacement"] = "acceleration",
    unit: Literal["m", "mm", "g"] = "m",
) -> NDArray[np.complex128]:
    """Convert response-over-force FRFs to accelerance in (m/s²)/N.

    For harmonic motion ``x(t) = X e^{iωt}``, ``ω = 2πf``: ``A = iω V = −ω² X``.
    ``unit`` is the response unit: metres (m, m/s, m/s²), millimetres (mm, mm/s, mm/s²) or
    standard gravity (only for acceleration, 1 g = 9.80665 m/s²).

    Parameters
    ----------
    H : ndarray, shape (n_lines, ...), complex
    frequencies_hz : ndarray, shape (n_lines,)
    """
    h: NDArray[np.complex128] = np.asarray(H, dtype=np.complex128)
    f = np.asarray(frequencies_hz, dtype=float)
    if h.shape[0] != f.shape[0]:
        raise DataError(f"H has {h.shape[0]} lines but the frequency axis has {f.shape[0]}")
    if unit == "g":
        if quantity != "acceleration":
            raise DataError("unit 'g' applies only to acceleration FRFs; use 'm' or 'mm'")
        factor: float = STANDARD_GRAVITY
    elif unit == "mm":
        factor = 1e-3
    elif unit == "m":
        factor = 1.0
    else:
        raise DataError(f"unit {unit!r} is unknown; use 'm', 'mm' or 'g'")
    w = (2 * np.pi * f).reshape((-1,) + (1,) * (h.ndim - 1))
    out: NDArray[np.complex128]
    if quantity == "acceleration":
        out = h * factor
        return out
    if quantity == "velocity":
        out = h * factor * (1j * w)
        return out
    if quantity == "displacement":
        out = h * (factor * (-(w**2)))
        return out
    raise DataError(f"quantity {quantity!r} is unknown; use acceleration, velocity or displacement")

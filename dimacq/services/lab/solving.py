"""Analysis: DIM solutions of stored FRF sets, and the figure of a stored solution.

:meth:`AnalysisService.solve` solves an FRF set with :class:`SolveOptions` (plain DIM, or the
selection steps of :mod:`dimacq.services.solve.analysis`) and stores the result with its options.
:meth:`AnalysisService.solution_spectrum` gives the per-line estimates behind a stored solution
from the stored result and options (the channels and inputs it used, its known values, length
unit, band and orientation repair), so its figure shows the solution that was stored.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, field_validator

from dimacq.errors import DataError, SetupError
from dimacq.model.frf import FrfData
from dimacq.model.properties import inertia_to_vector
from dimacq.model.setup import TestSetup
from dimacq.pipeline.chain_calibration import ChainCalibration
from dimacq.services.lab.request_once import RequestOnce
from dimacq.services.lab.store import StoredSolution, TestStore

__all__ = ["AnalysisService", "Param", "SolutionSpectrum", "SolveOptions"]

Param = Literal["m", "cx", "cy", "cz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz"]

_KNOWN_UNIT = {"m": "kg", "cx": "m", "cy": "m", "cz": "m"} | dict.fromkeys(
    ("Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz"), "kg m²"
)
#: Largest magnitude of a known value (SI): far beyond any structure a lab weighs (10⁹ kg,
#: 10⁶ m, 10¹⁵ kg m²), and small enough that the solver's products stay finite in float64.
KNOWN_LIMIT = {"m": 1e9, "cx": 1e6, "cy": 1e6, "cz": 1e6} | dict.fromkeys(
    ("Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz"), 1e15
)
_POSITIVE = frozenset({"m", "Ixx", "Iyy", "Izz"})


class ReferenceMassIn(BaseModel):
    """A weighed reference body (``config/reference-block/mass.toml``)."""

    model_config = ConfigDict(extra="forbid")

    mass_kg: float = Field(gt=0, lt=1e6, allow_inf_nan=False, description="weighed mass, kg")
    u_kg: float = Field(
        default=0.0, ge=0, lt=1e6, allow_inf_nan=False, description="standard uncertainty, kg"
    )


class SolveOptions(BaseModel):
    """How to solve an FRF set (validated once, where the options come in)."""

    model_config = ConfigDict(extra="forbid")

    band_hz: tuple[float, float] | None = None
    known: dict[Param, float] = Field(default_factory=dict)
    length_unit: Literal["m", "cm", "mm"] | None = Field(
        default=None,
        description="length unit the solver works in (weights moment rows against force rows; "
        "default: the setup's), as `dimacq solve --length-unit`",
    )
    reference_point_m: tuple[FiniteFloat, FiniteFloat, FiniteFloat] | None = Field(
        default=None,
        description="point P (GCS, m) the inertia is reported about (default: the setup's), "
        "as `dimacq solve --reference-point`",
    )
    scale_to_mass_kg: FiniteFloat | None = Field(
        default=None,
        gt=0,
        le=KNOWN_LIMIT["m"],
        description="scale the FRFs so that the band mass equals this mass, kg (FRF scaling, "
        "thesis §3.2.2.1; the factor is `frf_scale_factor` in the result), as "
        "`dimacq solve --scale-to-mass`",
    )
    method: Literal["joint", "mean"] = "joint"
    select_responses: bool = Field(
        default=True, description="perimeter response selection (default on)"
    )
    select_inputs: bool = Field(default=True, description="jackknife input selection (default on)")
    repair_orientation: bool = False
    auto_band: bool = Field(
        default=True, description="choose the band automatically (default on; band_hz overrides)"
    )
    geometry_uncertainty: bool = Field(
        default=True,
        description="include the setup's stated geometry uncertainty in the 95 % intervals",
    )
    unbiased: bool = Field(
        default=True,
        description="output-error (maximum-likelihood) estimate with the FRF noise from the data",
    )
    refine_geometry: bool = Field(
        default=True,
        description="estimate sensor rotations/offsets and input lines of action with the properties",
    )
    residual_flexibility: bool = Field(
        default=False, description="fit residual terms of elastic modes above the band"
    )
    reference_mass: ReferenceMassIn | None = Field(
        default=None,
        description="the FRF set was measured on a reference body of this weighed mass: the "
        "solution carries the chain calibration it gives (chain_calibration, role measured)",
    )
    chain_calibration_id: int | None = Field(
        default=None,
        ge=1,
        le=2**63 - 1,
        description="apply the chain calibration measured by this solution (a reference_mass "
        "solve): FRFs × factor, the hammer's certificate uncertainty replaced by u_rel",
    )

    @field_validator("band_hz")
    @classmethod
    def _band_ascending(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not (0 <= v[0] < v[1] and math.isfinite(v[1])):
            raise ValueError(
                f"band_hz {list(v)}: give [low, high] with 0 ≤ low < high, finite, in Hz"
            )
        return v

    @field_validator("known")
    @classmethod
    def _known_physical(cls, v: dict[str, float]) -> dict[str, float]:
        for k, x in v.items():
            if not math.isfinite(x) or abs(x) > KNOWN_LIMIT[k]:
                raise ValueError(
                    f"known {k} = {x}: give a finite value within ±{KNOWN_LIMIT[k]:g} "
                    f"({_KNOWN_UNIT[k]})"
                )
            if k in _POSITIVE and not x > 0:
                raise ValueError(
                    f"known {k} = {x}: a {'mass' if k == 'm' else 'moment of inertia'} must be "
                    f"> 0 ({_KNOWN_UNIT[k]})"
                )
        return v


@dataclass(frozen=True)
class SolutionSpectrum:
    """The per-line estimates behind a stored solution.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
        Every line of the FRF set.
    per_line : ndarray, shape (n_lines, 10)
        ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` per line (kg, m, kg m²; inertia about
        the reference point), from the channels and inputs the solution used.
    band_hz : (lo, hi)
        The band of the stored solution.
    headline : ndarray, shape (10,)
        The stored solution's estimate, same layout.
    """

    frequencies_hz: NDArray[np.float64]
    per_line: NDArray[np.float64]
    band_hz: tuple[float, float]
    headline: NDArray[np.float64]


class AnalysisService:
    """Solve stored FRF sets; store and draw the solutions."""

    def __init__(self, store: TestStore) -> None:
        self.store = store
        self._once = RequestOnce("solve")

    def solve(
        self, frf_id: int, options: SolveOptions, idempotency_key: str | None = None
    ) -> StoredSolution | None:
        """DIM solution of an FRF set through :func:`dimacq.services.solve.analysis.analyse`; stored
        with its options. None if the set does not exist.

        ``options``: ``band_hz`` (overrides the automatic band), ``known``, ``length_unit``,
        ``method``, and the analysis service's switches (``select_responses``,
        ``select_inputs``, ``auto_band``, ``geometry_uncertainty``: default on;
        ``repair_orientation``). The result carries ``verdict`` (ok/warn/fail) and
        ``verdict_reasons``; a ``fail`` is stored and returned like any other, its reasons say
        why it must not be used.

        One solution per request (:class:`~dimacq.services.lab.request_once.RequestOnce`): an
        identical solve (same FRF set, same options) while one runs is refused
        (:class:`~dimacq.errors.DeviceStateError`, naming it); ``idempotency_key`` sent again
        with the same request returns the solution it stored.
        """
        request = json.dumps([frf_id, options.model_dump(mode="json")], sort_keys=True)
        with self._once.once(
            request,
            idempotency_key,
            f"a solve of FRF set {frf_id} with the same options",
            f"its solution is stored once when it ends (GET /api/solutions?frf_id={frf_id})",
        ) as slot:
            if slot.replay is not None:
                stored = self.store.solution(slot.replay)
                if stored is not None:
                    return stored
            got = self.store.frf(frf_id)
            if got is None:
                return None
            frf, setup = got
            frf, setup, gamma = self._prepared(frf, setup, options)
            result = self._analyse(frf, setup, options).to_json()
            if gamma is not None:
                result["frf_scale_factor"] = gamma
            sol = self.store.save_solution(frf_id, options.model_dump(), result)
            slot.done(sol.id)
            return sol

    def chain(self, solution_id: int | None) -> ChainCalibration | None:
        """The chain calibration a stored reference-mass solve measured (None for no id).

        Raises
        ------
        SetupError
            No such solution, or one that measured no chain calibration (not a reference-mass
            solve, or refused: its verdict was fail).
        """
        if solution_id is None:
            return None
        sol = self.store.solution(solution_id)
        where = f"chain_calibration_id {solution_id}"
        if sol is None:
            raise SetupError(f"{where}: no such solution; give the id of a reference-mass solve")
        doc = sol.result.get("chain_calibration")
        if not doc or doc.get("role") != "measured":
            raise SetupError(
                f"{where}: that solution measured no chain calibration (solve the reference "
                "body's FRF set with reference_mass, and check its verdict is not fail)"
            )
        cal = ChainCalibration.from_json(doc, where)
        return replace(cal, source=cal.source or f"solution {solution_id} (FRF set {sol.frf_id})")

    @staticmethod
    def _prepared(
        frf: FrfData, setup: TestSetup, options: SolveOptions
    ) -> tuple[FrfData, TestSetup, float | None]:
        """The FRFs and setup as the options ask (``reference_point_m`` replaces the setup's
        point P; ``scale_to_mass_kg`` scales the FRFs by ``γ``), and ``γ`` (None: not scaled);
        what ``dimacq solve --reference-point --scale-to-mass`` does."""
        from dimacq.pipeline.dim import scale_to_known_mass

        if options.reference_point_m is not None:
            setup = setup.model_copy(update={"reference_point_m": options.reference_point_m})
        if options.scale_to_mass_kg is None:
            return frf, setup, None
        gamma, _ = scale_to_known_mass(
            frf,
            setup,
            options.scale_to_mass_kg,
            band_hz=options.band_hz,
            length_unit=options.length_unit,
        )
        return frf.scaled(gamma), setup, float(gamma)

    @staticmethod
    def _known(setup: TestSetup, options: SolveOptions) -> dict[str, float]:
        known = setup.known.as_dict()
        known.update({k: float(v) for k, v in options.known.items()})
        return known

    def _analyse(self, frf: FrfData, setup: TestSetup, options: SolveOptions) -> Any:
        from dimacq.services.solve.analysis import AnalysisOptions, analyse

        return analyse(
            frf,
            setup,
            AnalysisOptions(
                select_responses=options.select_responses,
                select_inputs=options.select_inputs,
                repair_orientation=options.repair_orientation,
                auto_band=options.auto_band,
                band_hz=options.band_hz,
                known=self._known(setup, options),
                length_unit=options.length_unit,
                method=options.method,
                geometry_samples=400 if options.geometry_uncertainty else 0,
                unbiased=options.unbiased,
                refine_geometry=options.refine_geometry,
                residual_flexibility=options.residual_flexibility,
                reference_mass=(
                    (options.reference_mass.mass_kg, options.reference_mass.u_kg)
                    if options.reference_mass is not None
                    else None
                ),
                chain=self.chain(options.chain_calibration_id),
            ),
        )

    # ------------------------------------------------------------------ the stored solution
    def solution_spectrum(self, solution_id: int) -> SolutionSpectrum | None:
        """Per-line estimates of a stored solution over the whole FRF set.

        Uses what the stored solution used: its setup (with the orientation repair when its
        options asked for one), the response channels and inputs it kept (``excluded_responses``
        and ``excluded_inputs`` of the result), its known values and length unit. The headline
        and the band are the stored ones.
        """
        from dimacq.pipeline.dim import assemble, solve_system
        from dimacq.pipeline.selection._common import response_geometry

        sol = self.store.solution(solution_id)
        if sol is None:
            return None
        got = self.store.frf(sol.frf_id)
        if got is None:
            raise DataError(f"solution {solution_id}: its FRF set {sol.frf_id} is missing")
        frf, setup = got
        res = sol.result
        stored_options = SolveOptions.model_validate(sol.options)
        # the stored run's point P, FRF scale and chain calibration (older solutions have none)
        if stored_options.reference_point_m is not None:
            setup = setup.model_copy(update={"reference_point_m": stored_options.reference_point_m})
        if res.get("frf_scale_factor") is not None:
            frf = frf.scaled(float(res["frf_scale_factor"]))
        if (res.get("chain_calibration") or {}).get("role") == "applied":
            frf = frf.scaled(float(res["chain_calibration"]["factor"]))
        setup_used = setup
        if sol.options.get("repair_orientation"):  # the stored run's repaired setup
            setup_used = self._analyse(frf, setup, stored_options).setup_used
        excluded_resp = list(res.get("excluded_responses", []))
        excluded_in = list(res.get("excluded_inputs", []))
        channels = response_geometry(frf, setup).channels
        weights = np.array([_pair(c) not in excluded_resp for c in channels], dtype=float)
        keep = np.nonzero([_pair(c) not in excluded_in for c in frf.inputs])[0]
        system = assemble(
            frf, setup_used, length_unit=res["length_unit"], response_weights=weights
        ).select_inputs(keep)
        per_line = solve_system(
            system, known=res["known"], method=res["method"], check_plausibility=False
        ).per_line
        lo, hi = res["band_hz"]
        return SolutionSpectrum(
            frequencies_hz=np.asarray(frf.frequencies_hz, float),
            per_line=np.asarray(per_line, float),
            band_hz=(float(lo), float(hi)),
            headline=_parameters(res),
        )

    def solution_figure(self, solution_id: int, fmt: Literal["png", "svg"] = "png") -> bytes | None:
        """Parameters against frequency with the band and the stored estimate (thesis Fig. 25)."""
        from dimacq.plotting.figures import parameters_vs_frequency_figure

        spec = self.solution_spectrum(solution_id)
        if spec is None:
            return None
        fig = parameters_vs_frequency_figure(
            spec.frequencies_hz, spec.per_line, spec.band_hz, headline=spec.headline
        )
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt, dpi=110)
        return buf.getvalue()


def _pair(c: Any) -> dict[str, int]:
    return {"node": int(c.node), "direction": int(c.direction)}


def _parameters(result: Mapping[str, Any]) -> NDArray[np.float64]:
    """``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` of a result document (CG in the GCS,
    inertia about the reference point), the layout of the solver's parameters."""
    return np.concatenate(
        [
            [float(result["mass_kg"])],
            np.asarray(result["cg_m"], float),
            inertia_to_vector(np.asarray(result["inertia_p_kgm2"], float)),
        ]
    )

"""``dimacq solve`` on the shipped example and on two noisy simulated sets gives the numbers it
gave before the speed work (#27), within what two machines agree on.

``six_triax_solve_reference.json`` is the ``--json`` output of
``dimacq solve config/examples/six_triax_setup.toml config/examples/six_triax_frf.uff``; only
``output_error.elapsed_s`` (a wall-clock time) was removed. The speed-ups of issue #27 (caching,
vectorising) were checked against the output of the code at 16dff20; the file was then
regenerated when the method itself changed (issue 22: the output-error line weights, the
precision floor, the mass-line cross-check and the reactions' noise keys; issue 23: the load
cells' corrections). Regenerate it only with a method change, and say which in the commit.
The noisy sets (``solve_reference/<scenario>.json``: ``dimacq simulate SCENARIO --noise 0.01``,
seed 0, solved by the default ``dimacq solve``; written by
``tests/scripts/solve_reference_answers.py --write``) exercise what the noise-free example cannot
(band search, selections, jackknife, output-error iterations, geometry Monte Carlo on data that
move them).

**What a machine changes.** The BLAS kernel (AVX-512, AVX2 or SSE code paths of OpenBLAS, MKL,
Accelerate) and its thread count change the order of floating-point sums, so every number moves
by rounding, and an ill-conditioned step multiplies that: measured between an AVX-512 machine
(the references), an AVX2 one (``OPENBLAS_CORETYPE`` Haswell, the default there), its SSE path
(``NEHALEM``) and one or two threads, the estimates of the x38 set moved by up to 2e-7 of the
inertia tensor's scale (``Ixy`` by 5e-6 of itself), the noisy sets' standard errors by up to
6e-6 of themselves, the noise-free example's corrections' standard errors — rounding noise —
by up to 55 % of themselves (2.5e-4 of their geometry prior). So each number is compared on the
scale of the quantity it belongs to (:func:`tolerance`), not on its own digits:

- **properties** (mass, CG, inertia tensor, principal moments; estimates, band statistics, the
  cross-check's, the output-error parameters, the geometry tests' differences, the intervals'
  ends) to :data:`PROPERTY_TOL` of their scale: the mass; the radius of gyration
  ``√(I_max / m)`` for lengths; the largest principal moment for the tensor's elements (an
  off-diagonal product of 0.18 kg·m² in a tensor of 6.4e4 kg·m² is rounding at 1e-5 of itself).
  It protects the answer: a change of 1e-4 of the mass, the CG or the tensor fails;
- **standard errors** of the properties to :data:`UNCERTAINTY_RTOL` of themselves (they are
  not rounding noise: the geometry Monte Carlo and the lines' noise set them): a change of a
  geometry prior by 1 % moves them by ~1e-2 of themselves, and fails;
- **z-scores** (the cross-check's) to :data:`Z_TOL` standard errors;
- **geometry corrections** (sensors', load cells', inputs': values and standard errors) to
  :data:`CORRECTION_TOL` of their prior (``rotation_prior_deg``, ``offset_prior_mm``,
  ``moment_gain_prior_pct``, the inputs' ``geometry_uncertainty``): a correction that moves by a
  thousandth of what the prior allows fails; on a noise-free set their standard errors are
  rounding noise and are only held below :data:`NOISE_FREE_CORRECTION_SE` of the prior (the
  data determine the geometry to 1 % of the prior or better there);
- **statistics of a rounding residual** on a noise-free set (``residual_rel`` below
  :data:`ROUNDING_RESIDUAL`): the residual, the χ², the geometry test's statistic and the
  effective lines are rounding noise there; they are held at rounding level (the residual and
  χ² below :data:`ROUNDING_RESIDUAL`, the test's statistic below :data:`ROUNDING_RESIDUAL` of its
  critical value, the effective lines between 1 and the lines fitted), which a method that
  leaves a real residual fails;
- **the gauge modes' data-to-prior information**: the data's information on a gauge mode is a
  Schur complement of terms 1e8 apart (the similarity is an exact symmetry of the model): below
  1e-4 of the best-determined mode's it is rounding noise (the noise-free example's first mode
  reads −0.55 or +0.46); compared to :data:`GAUGE_RATIO_RTOL` and an absolute
  ``max(GAUGE_RATIO_ATOL, 1e-4 × the largest ratio)``. A diagnostic: the modes are fixed
  whatever it reads;
- **everything else** (counts, condition numbers, bands, excitation checks, noise estimates)
  to :data:`RTOL` of itself (and :data:`ATOL`); strings as they were except for the numbers they
  quote (to the digits they quote them with, or within the tolerance of the number they quote
  where that is a rounding-level statistic).

``tests/scripts/machine_independence.py`` runs these tests (or the suite) under the BLAS
variants above.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from dimacq.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "config" / "examples"
REFERENCE = Path(__file__).with_name("six_triax_solve_reference.json")
REFERENCE_DIR = Path(__file__).with_name("solve_reference")
#: Noisy whole-test sets made by ``dimacq simulate SCENARIO --noise 0.01`` (seed 0).
SIMULATED = ("calibration-mass-bungee", "x38-realistic")

#: anything without a scale of its own: relative to itself (bands, counts, condition numbers)
RTOL = 1e-6
ATOL = 1e-12
#: properties, relative to their scale (measured across machines: ≤ 2e-7)
PROPERTY_TOL = 1e-6
#: the properties' standard errors, relative to themselves (measured: ≤ 6e-6)
UNCERTAINTY_RTOL = 1e-4
#: a property's standard error below this fraction of the property's scale is rounding noise
#: (the noise-free example's band statistics' spreads: ~1e-15)
ROUNDING_SE = 1e-9
#: z-scores, in standard errors (measured: ≤ 1e-6)
Z_TOL = 1e-4
#: geometry corrections and their standard errors, relative to their prior (measured: ≤ 1e-5 on
#: the noisy sets)
CORRECTION_TOL = 1e-3
#: a noise-free set's corrections' standard errors are held below this fraction of the prior
NOISE_FREE_CORRECTION_SE = 1e-2
#: a test's statistic, relative to its critical value (measured: ≤ 5e-9)
STATISTIC_TOL = 1e-6
#: a residual below this (relative) is rounding noise: the set is noise-free
ROUNDING_RESIDUAL = 1e-6
#: the gauge modes' data-to-prior information ratios (see above)
GAUGE_RATIOS = ".output_error.gauge_modes.data_to_prior_information"
GAUGE_RATIO_RTOL = 0.05
GAUGE_RATIO_ATOL = 0.05
#: below this, an input's studentised residual in the input selection is rounding noise (the
#: noise-free example: all of them are ~1e-15), and which input is "least consistent" is arbitrary
ROUNDING_STATISTIC = 1e-12
SKIP = {".output_error.elapsed_s"}

#: the order of the properties in the geometry tests' ``difference`` lists
PROPERTIES = ("m", "cx", "cy", "cz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
#: a number inside a message ("rigid-body error ≤ 5.86e-16 (limit 0.02)")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_KEY = r"(?:^|[.\[])"
_MASS = re.compile(_KEY + r"(?:m|mass|mass_kg)(?:$|[.\[])")
_LENGTH = re.compile(_KEY + r"(?:c[xyz]|cg|cg_m)(?:$|[.\[])")
_INERTIA = re.compile(
    _KEY + r"(?:I[xyz]{2}(?:_cg|_p)?|I[123]|inertia(?:_cg|_p)?(?:_kgm2)?|principal"
    r"|principal_moments(?:_kgm2)?)(?:$|[.\[])"
)
_UNCERTAINTY = re.compile(
    r"standard_error|\.se_|_se_|\.std\b|dim_standard_error|comparison_standard_error"
)
_CORRECTION = re.compile(r"\.output_error\.(sensor|load_cell|input)_corrections\[(\d+)\]\.(\w+)")
_RESIDUAL_STATISTICS = (
    ".residual_rel",
    ".cross_check.residual_rel",
    ".output_error.chi2_reduced",
    ".output_error.noise.chi2_reduced",
    ".output_error.noise.chi2_reduced_stated_noise",
)


@dataclass(frozen=True)
class Scales:
    """The scales a solve's numbers belong to, from the reference answer."""

    mass_kg: float
    length_m: float
    inertia_kgm2: float
    noise_free: bool
    gauge_info: float
    geometry: dict[str, Any]

    @classmethod
    def of(cls, ref: dict[str, Any]) -> Scales:
        m = abs(float(ref["mass_kg"]))
        inertia = max(abs(float(v)) for v in ref["principal_moments_kgm2"])
        ratios = ref.get("output_error", {}).get("gauge_modes", {})
        ratios = ratios.get("data_to_prior_information") or [0.0]
        return cls(
            mass_kg=m,
            length_m=math.sqrt(inertia / m),
            inertia_kgm2=inertia,
            noise_free=float(ref.get("residual_rel", 1.0)) < ROUNDING_RESIDUAL,
            gauge_info=max(abs(float(v)) for v in ratios),
            geometry=dict(ref.get("geometry_uncertainty") or {}),
        )

    def of_property(self, path: str) -> float | None:
        """The scale of the property PATH names (None: not a property)."""
        if _INERTIA.search(path):
            return self.inertia_kgm2
        if _LENGTH.search(path):
            return self.length_m
        if _MASS.search(path):
            return self.mass_kg
        return None


def tolerance(path: str, ref: float, doc: dict[str, Any], scales: Scales) -> float | str:
    """How far the number at PATH (reference value REF, reference document DOC) may move on
    another machine: an absolute tolerance, or ``"rounding"`` when it is a statistic of a
    rounding residual (held at rounding level instead, :func:`_at_rounding_level`)."""
    if path.startswith(GAUGE_RATIOS):
        atol = max(GAUGE_RATIO_ATOL, 1e-4 * scales.gauge_info)
        return GAUGE_RATIO_RTOL * abs(ref) + atol
    if scales.noise_free and (
        path in _RESIDUAL_STATISTICS
        or path.startswith(".output_error.geometry_test.statistic")
        or path.endswith(("effective_lines", "n_lines_effective"))
    ):
        return "rounding"
    test = re.match(r"\.output_error\.(geometry_test|adequacy)\.statistic", path)
    if test is not None:
        # a χ²-like statistic, on the scale of the critical value it is tested against
        critical = float(doc["output_error"][test.group(1)]["critical_value"])
        return RTOL * abs(ref) + STATISTIC_TOL * critical
    if path.endswith("robust_factor_max"):
        return UNCERTAINTY_RTOL * abs(ref)  # a ratio of noise estimates, second-order
    if ".cross_check.z." in path or path.endswith("max_abs_z"):
        return Z_TOL
    corr = _CORRECTION.match(path)
    if corr is not None:
        kind, i, key = corr.group(1), int(corr.group(2)), corr.group(3)
        prior = _prior(kind, key, doc["output_error"][f"{kind}_corrections"][i], scales)
        if prior is not None:
            if scales.noise_free and "_se_" in key:
                return "rounding"
            return CORRECTION_TOL * prior
    diff = re.match(r"\.output_error\.(?:geometry_test|adequacy)\.difference\[(\d+)\]", path)
    if diff is not None:
        scale = scales.of_property(f".{PROPERTIES[int(diff.group(1))]}")
        assert scale is not None
        return PROPERTY_TOL * scale
    scale = scales.of_property(path)
    if scale is not None:
        if _UNCERTAINTY.search(path):
            return UNCERTAINTY_RTOL * abs(ref) + ROUNDING_SE * scale
        return PROPERTY_TOL * scale
    if path.startswith(".principal_axes"):
        return PROPERTY_TOL  # unit vectors
    return RTOL * abs(ref) + ATOL


_PRIOR_KEYS = {
    "rotation": "rotation_prior_deg",
    "offset": "offset_prior_mm",
    "moment_gain": "moment_gain_prior_pct",
}


def _prior(kind: str, key: str, corr: dict[str, Any], scales: Scales) -> float | None:
    """The prior σ a correction's value or standard error KEY belongs to, in its unit (None:
    the key is no correction, e.g. the prior itself)."""
    if "_prior_" in key:
        return None
    if kind == "input":
        if key.startswith("line_of_action"):
            return float(scales.geometry.get("line_of_action_deg") or 1.0)
        if key.startswith("offset"):
            return 1e3 * float(scales.geometry.get("input_position_m") or 0.002)
        return None
    for stem, prior_key in _PRIOR_KEYS.items():
        if key.startswith(stem) and corr.get(prior_key) is not None:
            return float(corr[prior_key])
    return None


def _at_rounding_level(
    path: str, got: float, ref: float, doc: dict[str, Any], scales: Scales
) -> bool:
    """A statistic of a noise-free set's residual stays at rounding level (both answers)."""
    if path.startswith(".output_error.geometry_test.statistic"):
        bound = ROUNDING_RESIDUAL * float(doc["output_error"]["geometry_test"]["critical_value"])
        return abs(got) <= bound and abs(ref) <= bound
    if path.endswith(("effective_lines", "n_lines_effective")):
        n = float(doc.get("cross_check", {}).get("n_lines") or 0) or math.inf
        return 1.0 <= got <= max(n, ref)
    corr = _CORRECTION.match(path)
    if corr is not None:
        kind, i, key = corr.group(1), int(corr.group(2)), corr.group(3)
        prior = _prior(kind, key, doc["output_error"][f"{kind}_corrections"][i], scales)
        assert prior is not None
        return abs(got) <= NOISE_FREE_CORRECTION_SE * prior
    return abs(got) <= ROUNDING_RESIDUAL and abs(ref) <= ROUNDING_RESIDUAL


def simulate(scenario: str, folder: Path) -> Path:
    """``dimacq simulate SCENARIO --noise 0.01`` (seed 0) into FOLDER; the UFF file's path."""
    path = folder / f"{scenario}.uff"
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(
            ["simulate", scenario, "--noise", "0.01", "--frf", str(path),
             "--truth", str(folder / f"{scenario}.truth.json")]
        )  # fmt: skip
    assert rc == 0
    return path


def solve_json(files: list[str], out: Path) -> Any:
    """The ``--json`` document of a default ``dimacq solve FILES``."""
    rc = main(["solve", *files, "--json", str(out)])
    assert rc in (0, 3)
    return json.loads(out.read_text())


def compare(got: Any, ref: Any, path: str, bad: list[str]) -> None:
    """Append to BAD every number, string or key of GOT that differs from REF by more than
    its tolerance (see the module doc)."""
    scales = Scales.of(ref)
    _compare(_unnamed_rounding(got), _unnamed_rounding(ref), path, bad, ref, scales)


def _unnamed_rounding(doc: Any) -> Any:
    """A copy of DOC without the input named as least consistent where every input's residual
    is rounding noise (its statistic, still compared, below :data:`ROUNDING_STATISTIC`)."""
    sel = doc.get("input_selection") if isinstance(doc, dict) else None
    if not isinstance(sel, dict) or not sel.get("cycles"):
        return doc
    doc = json.loads(json.dumps(doc))
    sel = doc["input_selection"]
    for k, cyc in enumerate(sel["cycles"]):
        if float(cyc.get("statistic_removed") or 1.0) < ROUNDING_STATISTIC:
            cyc["removed"] = "(rounding noise)"
            if k == sel.get("chosen_cycle") and isinstance(sel.get("stop_reason"), str):
                sel["stop_reason"] = re.sub(
                    r"input \S+ has", "input (rounding noise) has", sel["stop_reason"]
                )
    return doc


def _compare(
    got: Any, ref: Any, path: str, bad: list[str], doc: dict[str, Any], scales: Scales
) -> None:
    if path in SKIP:
        return
    if isinstance(ref, dict):
        assert isinstance(got, dict), path
        missing, extra = set(ref) - set(got), set(got) - set(ref) - {"elapsed_s"}
        if missing or extra:
            bad.append(f"{path}: keys missing {sorted(missing)}, extra {sorted(extra)}")
        for k in (k for k in ref if k in got):
            _compare(got[k], ref[k], f"{path}.{k}", bad, doc, scales)
    elif isinstance(ref, list):
        if not isinstance(got, list) or len(got) != len(ref):
            bad.append(f"{path}: {got!r} != {ref!r}")
            return
        for i, (g, r) in enumerate(zip(got, ref, strict=True)):
            _compare(g, r, f"{path}[{i}]", bad, doc, scales)
    elif isinstance(ref, float) and not isinstance(got, bool) and isinstance(got, int | float):
        tol = tolerance(path, ref, doc, scales)
        if tol == "rounding":
            if not _at_rounding_level(path, got, ref, doc, scales):
                bad.append(f"{path}: {got!r} (reference {ref!r}) is not at rounding level")
        elif not abs(got - ref) <= float(tol):
            bad.append(
                f"{path}: {got!r} != {ref!r} (off by {abs(got - ref):.2e}, allowed {tol:.1e})"
            )
    elif isinstance(ref, str) and isinstance(got, str) and got != ref:
        # Messages quote numbers to a few digits: the same text, and the quoted numbers within
        # the tolerance of the numbers they quote (a rounding-noise 5.86e-16 may read 5.9e-16;
        # on a noise-free set a quoted statistic of the rounding residual stays below
        # ROUNDING_RESIDUAL, as the statistic itself).
        g_num, r_num = _NUMBER.findall(got), _NUMBER.findall(ref)
        same_text = _NUMBER.sub("#", got) == _NUMBER.sub("#", ref) and len(g_num) == len(r_num)
        if not same_text or any(
            not _same_quote(float(g), float(r), scales) for g, r in zip(g_num, r_num, strict=True)
        ):
            bad.append(f"{path}: {got!r} != {ref!r}")
    elif got != ref:
        bad.append(f"{path}: {got!r} != {ref!r}")


def _same_quote(got: float, ref: float, scales: Scales) -> bool:
    """A number quoted in a message: to 5e-3 of itself (three digits), or both at rounding level
    on a noise-free set."""
    if abs(got - ref) <= max(RTOL, 5e-3) * abs(ref) + ATOL:
        return True
    return scales.noise_free and abs(got) <= ROUNDING_RESIDUAL and abs(ref) <= ROUNDING_RESIDUAL


def test_shipped_example_solves_to_the_numbers_before_the_speed_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sol.json"
    rc = main(
        [
            "solve",
            str(EXAMPLES / "six_triax_setup.toml"),
            str(EXAMPLES / "six_triax_frf.uff"),
            "--json",
            str(out),
        ]
    )
    capsys.readouterr()
    assert rc == 0
    bad: list[str] = []
    compare(json.loads(out.read_text()), json.loads(REFERENCE.read_text()), "", bad)
    assert not bad, f"{len(bad)} numbers changed:\n" + "\n".join(bad[:40])


@pytest.mark.slow
@pytest.mark.parametrize("scenario", SIMULATED)
def test_noisy_sets_solve_to_the_numbers_before_the_speed_work(
    scenario: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    got = solve_json([str(simulate(scenario, tmp_path))], tmp_path / "sol.json")
    capsys.readouterr()
    bad: list[str] = []
    compare(got, json.loads((REFERENCE_DIR / f"{scenario}.json").read_text()), "", bad)
    assert not bad, f"{len(bad)} numbers changed:\n" + "\n".join(bad[:40])


def test_the_comparison_sees_a_change() -> None:
    """Each tolerance lets rounding through and stops a change of the method's answer."""
    ref = json.loads(REFERENCE.read_text())
    got = json.loads(REFERENCE.read_text())
    got["mass_kg"] *= 1 + 1e-5  # the answer by 1e-5
    got["inertia_p_kgm2"][0][0] *= 1 + 1e-5
    got["cg_m"][2] += 1e-5 * 0.2  # 1e-5 of the radius of gyration (0.20 m)
    got["uncertainty"]["Ixx"]["standard_error"] *= 1.01  # a prior by 1 % moves it so
    got["cross_check"]["z"]["mass"] += 1e-3
    sensor = got["output_error"]["sensor_corrections"][0]
    sensor["rotation_deg"][0] += 2e-3 * sensor["rotation_prior_deg"]
    # noise-free: a correction's standard error of 2 % of its prior is no rounding noise
    sensor["offset_se_mm"][0] = 0.02 * sensor["offset_prior_mm"]
    got["residual_rel"] = 1e-5  # a real residual on the noise-free example
    got["verdict"] = "other"
    got["band_selection"]["reason"] = ref["band_selection"]["reason"].replace(
        "91 lines", "92 lines"
    )
    got["verdict_reasons"][0]["message"] = ref["verdict_reasons"][0]["message"].replace(
        "5.86e-16", "5.9e-16"
    )
    # what another machine's rounding does (measured: AVX2 against the AVX-512 reference)
    got["cross_check"]["residual_rel"] = 2 * ref["cross_check"]["residual_rel"]
    got["output_error"]["sensor_corrections"][1]["rotation_se_deg"][0] *= 1.5
    got["uncertainty"]["n_lines_effective"] = 62.5
    got["output_error"]["gauge_modes"]["data_to_prior_information"][0] = 0.46
    got["inertia_p_kgm2"][1][2] *= 1 + 1e-5  # a product of 1e-5 kg m² in a 0.52 kg m² tensor
    bad: list[str] = []
    compare(got, ref, "", bad)
    assert sorted(b.split(":")[0] for b in bad) == sorted(
        [
            ".mass_kg",
            ".cg_m[2]",
            ".inertia_p_kgm2[0][0]",
            ".residual_rel",
            ".uncertainty.Ixx.standard_error",
            ".band_selection.reason",
            ".verdict",
            ".cross_check.z.mass",
            ".output_error.sensor_corrections[0].rotation_deg[0]",
            ".output_error.sensor_corrections[0].offset_se_mm[0]",
        ]
    ), bad

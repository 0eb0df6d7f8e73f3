"""Chain calibration on a reference mass (dimacq.pipeline.chain_calibration and its use by the
analysis): closed form, refusals, and the whole loop on virtual-lab FRFs whose hammer is off."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dimacq.errors import DataError, SetupError
from dimacq.pipeline.chain_calibration import ChainCalibration, chain_calibration
from dimacq.services.solve.analysis import AnalysisOptions, analyse
from dimacq.simulators.lab.forward import REFERENCE_BLOCK, reference_block_drawing
from dimacq.simulators.lab.scenarios import build_scenario


def test_factor_and_uncertainty_closed_form() -> None:
    cal = chain_calibration(49.0, 0.049, 48.0, 0.0048)
    assert cal.factor == pytest.approx(49.0 / 48.0, rel=1e-15)
    assert cal.u_rel == pytest.approx(math.sqrt(1e-6 + 1e-8), rel=1e-12)
    back = ChainCalibration.from_json(cal.to_json())
    assert back == cal


@pytest.mark.parametrize(
    ("args", "err", "words"),
    [
        ((60.0, 0.1, 48.0, 0.005), DataError, "wrong sensitivity"),
        ((-1.0, 0.1, 48.0, 0.005), DataError, "non-physical"),
        ((48.0, 0.1, 0.0, 0.005), SetupError, "weighed mass"),
        ((48.0, 0.1, 48.0, -1.0), SetupError, "≥ 0"),
    ],
)
def test_refusals_name_the_problem(args, err, words) -> None:
    with pytest.raises(err, match=words):
        chain_calibration(*args)


def test_from_json_checks_the_document() -> None:
    with pytest.raises(SetupError, match="not a chain calibration"):
        ChainCalibration.from_json({"factor": 1.0})
    good = chain_calibration(48.5, 0.05, 48.0, 0.005).to_json()
    with pytest.raises(SetupError, match="factor"):
        ChainCalibration.from_json({**good, "factor": 1.5})


def test_drawing_matches_the_block() -> None:
    """The drawing's reference point is the block's centre, i.e. its CG (homogeneous box), and
    the box's inertia is m/12 (b² + c², ...)."""
    d = reference_block_drawing()
    np.testing.assert_allclose(d.reference_point_m, REFERENCE_BLOCK.cg_m, atol=1e-15)
    assert REFERENCE_BLOCK.mass_kg == pytest.approx(2700 * 0.32 * 0.28 * 0.20)
    assert REFERENCE_BLOCK.inertia_cg_kgm2[2, 2] == pytest.approx(
        REFERENCE_BLOCK.mass_kg / 12 * (0.32**2 + 0.28**2)
    )
    assert len(d.responses) == 24 and len(d.excitations) == 24 and len(d.load_cells) == 1


@pytest.mark.slow
def test_hammer_error_calibrated_out_on_another_body() -> None:
    """A hammer certificate 2 % off scales every FRF (accelerations and reactions) by κ = 1.02:
    the calibration mass then measures 2 % light. The chain factor measured on the reference
    block (its drawing's geometry, its weighed mass) with the same κ brings the calibration mass
    back within the chain's stated uncertainty, and the solve's intervals carry it."""
    kappa = 1.02
    block = build_scenario("reference-block-bungee", 3)
    frf_b = block.model_frf(noise=0.01).scaled(kappa)
    rep_b = analyse(
        frf_b,
        reference_block_drawing(),
        AnalysisOptions(reference_mass=(REFERENCE_BLOCK.mass_kg, 0.005), geometry_samples=100),
    )
    cal_doc = rep_b.chain_calibration
    assert cal_doc is not None and cal_doc["role"] == "measured"
    assert rep_b.setup_used.transducer_uncertainty.force_sensitivity_rel == 0.0
    cal = ChainCalibration.from_json(cal_doc)
    assert abs(cal.factor * kappa - 1) < 3 * cal.u_rel  # γ = 1/κ within its uncertainty
    assert 0 < cal.u_rel < 0.005
    art = build_scenario("calibration-mass-bungee", 4)
    frf_a = art.model_frf(noise=0.01).scaled(kappa)
    plain = analyse(frf_a, art.model.setup, AnalysisOptions(geometry_samples=0))
    assert plain.result.mass_kg / art.truth.mass_kg - 1 == pytest.approx(-0.0196, abs=0.003)
    fixed = analyse(frf_a, art.model.setup, AnalysisOptions(chain=cal, geometry_samples=100))
    err = fixed.result.mass_kg / art.truth.mass_kg - 1
    assert abs(err) < 3 * cal.u_rel + 0.001, err
    assert fixed.chain_calibration is not None and fixed.chain_calibration["role"] == "applied"
    tu = fixed.setup_used.transducer_uncertainty
    assert tu.source == "chain" and tu.force_sensitivity_rel == pytest.approx(cal.u_rel)
    lo, hi = fixed.uncertainty.parameters["m"].ci95
    assert lo <= art.truth.mass_kg <= hi
    with pytest.raises(SetupError, match="either"):
        analyse(frf_a, art.model.setup, AnalysisOptions(chain=cal, reference_mass=(1.0, 0.0)))


def test_no_chain_factor_from_a_failed_solve() -> None:
    """A reference solve whose verdict is fail gives no factor, and says why: the block's FRFs
    solved with the calibration mass's geometry (same node numbers, other positions)."""
    block = build_scenario("reference-block-bungee", 3)
    wrong = build_scenario("calibration-mass-bungee", 3).model.setup
    rep = analyse(
        block.model_frf(noise=0.01),
        wrong,
        AnalysisOptions(
            reference_mass=(REFERENCE_BLOCK.mass_kg, 0.005),
            geometry_samples=0,
            # the verdict fails on the checks of the rigid solve (band, residual, plausibility);
            # the modal correction's fit of this non-rigid data (97 % of the CPU) is its tests'
            modal_correction="off",
        ),
    )
    assert rep.verdict == "fail"
    assert rep.chain_calibration is None and "chain_calibration" not in rep.to_json()
    assert rep.verdict_reasons[0].check == "chain_calibration"
    assert "no chain calibration" in rep.verdict_reasons[0].message

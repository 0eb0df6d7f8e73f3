"""The three modules split into packages (dimacq.pipeline.output_error, dimacq.pipeline.dim,
dimacq.io.uff): every name imported from them before the split still resolves there, to the very
object its new module defines, and each new module stays within the conventions' size."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: The names the old modules offered (their __all__ and constants) and the names that tests and
#: other modules import from them.
NAMES = {
    "dimacq.pipeline.output_error": (
        "ADEQUACY_P",
        "LINE_NOISE_HALF_WIDTH",
        "PRECISION_FLOOR_REL",
        "REACTION_SNR_LOW",
        "SMOOTH_FIT_RATIO",
        "OutputErrorOptions",
        "OutputErrorResult",
        "Problem",
        "effective_lines",
        "estimate_noise",
        "gauge_property_jacobian",
        "mass_matrix",
        "solve_output_error",
    ),
    "dimacq.pipeline.dim": (
        "Diagnostic",
        "DimResult",
        "DimSystem",
        "assemble",
        "design_matrices",
        "line_residuals",
        "plausibility",
        "scale_to_known_mass",
        "solve",
        "solve_joint",
        "solve_system",
    ),
    "dimacq.io.uff": (
        "ORDINATE_TYPES",
        "UffSource",
        "check_uff_geometry",
        "dump_uff",
        "read_frf_uff",
        "read_uff_test",
        "write_frf_uff",
        "write_uff_test",
        "Record",
        "common_axis",
    ),
}


@pytest.mark.parametrize("package", sorted(NAMES))
def test_old_names_resolve_to_their_new_home(package: str) -> None:
    pkg = importlib.import_module(package)
    for name in NAMES[package]:
        obj = getattr(pkg, name)
        home = getattr(obj, "__module__", None)
        if callable(obj) and home is not None and home.startswith(package + "."):
            # a function or class: the package's name is the submodule's object, not a copy
            assert getattr(importlib.import_module(home), name) is obj, f"{package}.{name}"
        elif callable(obj) and not isinstance(obj, type):
            pytest.fail(f"{package}.{name} is defined in {home}, not in the package")


def test_dim_solve_is_the_function_not_a_submodule() -> None:
    # the solver module is named solver.py: dimacq.pipeline.dim.solve stays the function
    from dimacq.pipeline import dim

    assert callable(dim.solve) and dim.solve.__name__ == "solve"


@pytest.mark.parametrize(
    "folder", ["dimacq/pipeline/output_error", "dimacq/pipeline/dim", "dimacq/io/uff"]
)
def test_split_modules_stay_readable(folder: str) -> None:
    for path in sorted((ROOT / folder).glob("*.py")):
        n = len(path.read_text(encoding="utf-8").splitlines())
        assert n <= 700, f"{path.relative_to(ROOT)} has {n} lines; split it along its seams"
        assert path.read_text(encoding="utf-8").lstrip().startswith('"""'), (
            f"{path.relative_to(ROOT)} has no module docstring; say what it holds"
        )

"""Write the candidate setups and expected properties of ``dimacq plan`` (``config/plans/``).

    python tests/scripts/make_plan_candidates.py

Each candidate setup is a scenario's TRUE geometry (``calibration-mass-bungee``, ``x38``: triaxes
and inputs as the virtual lab places them) plus extra candidate positions, some good (far from
the CG, on other faces) and some poor (near the CG, clustered), so that the choice matters. The
X-38's drogue-chute triaxes (1019–1021) are left out: they do not follow the vehicle in its band.
Extra triaxes are GCS-aligned; load cells and known properties are dropped (the plan's model is
the free-free rigid body). The properties file holds the scenario's truth (``mass_kg``, ``cg_m``,
``inertia_cg_kgm2``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dimacq.io.setup_file import save_setup
from dimacq.model.setup import Excitation, KnownProperties, ResponseChannel, TestSetup
from dimacq.simulators.lab.scenarios import build_scenario

OUT = Path(__file__).resolve().parents[2] / "config" / "plans"


def _triax(node: int, pos: tuple[float, float, float]) -> list[ResponseChannel]:
    return [
        ResponseChannel(
            node=node, direction=k + 1, position_m=pos, direction_gcs=tuple(np.eye(3)[k])
        )  # type: ignore[arg-type]
        for k in range(3)
    ]


def _input(node: int, pos: tuple[float, ...], d: tuple[float, ...]) -> Excitation:
    v = np.asarray(d, float)
    v /= np.linalg.norm(v)
    return Excitation(node=node, direction=1, position_m=pos, direction_gcs=tuple(v))  # type: ignore[arg-type]


def _write(name: str, scenario: str, drop: set[int], triaxes: list, inputs: list) -> None:
    built = build_scenario(scenario)
    true = built.model.setup
    responses = [c for c in true.responses if c.node not in drop]
    for node, pos in triaxes:
        responses += _triax(node, pos)
    setup = TestSetup(
        name=f"{name} candidates",
        reference_point_m=true.reference_point_m,
        length_unit=true.length_unit,
        responses=tuple(responses),
        excitations=tuple(true.excitations) + tuple(_input(*i) for i in inputs),
        known=KnownProperties(),
    )
    OUT.mkdir(parents=True, exist_ok=True)
    save_setup(setup, OUT / f"{name}-candidates.toml")
    t = built.truth
    props = {
        "mass_kg": t.mass_kg,
        "cg_m": t.cg_m.tolist(),
        "inertia_cg_kgm2": t.inertia_cg_kgm2.tolist(),
        "source": f"scenario {scenario} (seed {built.seed}) truth",
    }
    (OUT / f"{name}-properties.json").write_text(json.dumps(props, indent=2) + "\n")
    print(f"{name}: {len({c.node for c in responses})} triaxes, {len(setup.excitations)} inputs")


def main() -> None:
    # calibration mass: a block about x −0.1…0.2, y ±0.15, z −0.2…0.05 m
    _write(
        "calibration-mass",
        "calibration-mass-bungee",
        set(),
        [
            (11, (0.05, 0.0, 0.05)),  # top face, centre
            (12, (0.05, 0.0, -0.2)),  # bottom face, centre
            (13, (0.2, 0.0, -0.08)),  # +X face, centre
            (14, (0.03, 0.02, -0.06)),  # near the CG (poor)
            (15, (0.05, -0.02, -0.06)),  # near the CG (poor)
            (16, (-0.09, 0.0, -0.08)),  # −X face, centre
            (17, (0.19, 0.14, 0.04)),  # corner, beside node 8
            (18, (0.05, 0.15, -0.08)),  # +Y face, centre
        ],
        [
            (131, (0.05, -0.15, -0.08), (0, 1, 0)),  # −Y face through the middle
            (132, (0.05, 0.0, 0.05), (0, 0, -1)),  # top face, through the CG (poor)
            (133, (0.19, 0.14, 0.05), (0, 0, -1)),  # top face corners: rolling and pitching
            (134, (-0.09, -0.14, 0.05), (0, 0, -1)),
            (135, (0.2, -0.14, 0.0), (-1, 0, 0)),  # +X face, yawing
            (136, (0.2, 0.02, -0.08), (-1, 0, 0)),  # +X face, through the CG (poor)
        ],
    )
    # X-38-like vehicle: about x 0…9, y ±1.4, z 0…1.8 m
    _write(
        "x38",
        "x38",
        {1019, 1020, 1021},
        [
            (1031, (0.2, 0.0, 0.9)),  # nose
            (1032, (8.8, -1.2, 0.4)),  # tail, port
            (1033, (8.8, 1.2, 0.4)),  # tail, starboard
            (1034, (4.5, 0.0, 0.9)),  # near the CG (poor)
            (1035, (4.8, 0.2, 0.7)),  # near the CG (poor)
            (1036, (4.5, 1.4, 0.9)),  # mid side, starboard
            (1037, (4.5, -1.4, 0.9)),  # mid side, port
            (1038, (4.5, 0.0, 1.8)),  # top, middle
            (1039, (5.0, 0.2, 1.0)),  # near the CG (poor)
        ],
        [
            (2031, (0.1, 0.0, 0.9), (1, 0, 0)),  # nose, along the axis (poor for rotation)
            (2032, (8.9, 1.0, 1.0), (0, 0, -1)),  # tail corners, vertical: pitch and roll
            (2033, (8.9, -1.0, 1.0), (0, 0, -1)),
            (2034, (0.3, 1.0, 1.0), (0, -1, 0)),  # nose side: yaw
            (2035, (4.5, 0.0, 1.8), (0, 0, -1)),  # top, through the CG (poor)
            (2036, (4.5, 1.4, 0.9), (0, -1, 0)),  # side, through the CG (poor)
            (2037, (8.9, 0.0, 1.8), (0, 1, 0)),  # tail top: roll and yaw
            (2038, (0.3, -1.0, 1.5), (0, 0, -1)),  # nose top, port
        ],
    )


if __name__ == "__main__":
    main()

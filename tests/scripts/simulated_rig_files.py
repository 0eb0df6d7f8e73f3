"""Write the simulated lab's rig files and calibration certificates (run on demand:
``python tests/scripts/simulated_rig_files.py``).

The simulated lab's transducers have true sensitivities within their datasheet tolerance
(:mod:`dimacq.simulators.lab.transducers`) and every load cell its own gauge matrix. A real lab
knows them from calibration certificates that carry the calibrated value with its own error;
this script is that calibration lab. It writes, per rig:

- ``[[hammers]]`` / ``[[responses]]`` with ``sensitivity = true × (1 + ε)``, ``ε`` normal with
  :data:`CERTIFICATE_ERROR` standard deviation (seeded by the transducer's serial number);
- per load cell ``calibrations/lc-<node>.json`` with ``C = (I + E) S⁺``, ``E`` a 6×6 matrix of
  the same relative standard deviation (``dimacq loadcell calibrate --simulated`` replaces it
  in a scratch copy: static 0.03 %, inertial 0.15 % through these accelerometer certificates'
  common scale, their scatter taken out by the rigid-body gains);
- ``calibration_mass_setup.toml``: the calibration mass on cell 501 with its certificate
  (``[known]``), read by ``loadcell_bench.toml``'s ``[inertial]`` table, and
  ``calibration_mass_on_cell.toml``: the same mass standing on the cell (the circular check's
  ``check_setup_file``).

The service and the drivers read only these files; nothing else of the simulator's truth.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np

from dimacq.io.loadcell_calibration import LoadCellCalibration, write_calibration_json
from dimacq.model.setup import direction_label
from dimacq.simulators.lab import transducers as tr
from dimacq.simulators.lab.impact import virtual_lab
from dimacq.simulators.lab.scenarios import build_scenario

CONFIG = Path(__file__).resolve().parents[2] / "config"
#: Relative standard deviation of a calibration certificate's value.
CERTIFICATE_ERROR = 0.005

#: rig file → (scenario it is cabled for, header)
RIGS = {
    "rig.toml": (
        "calibration-mass-bungee",
        "the calibration mass (all calibration-mass-* scenarios): eight triaxial IEPE\n"
        "# accelerometers (nodes 1..8) on DAQ inputs 1..24, one roving impact hammer on input 0 and\n"
        "# the 6-DOF load cell (node 501) on the CAN amplifier with node id 1.",
    ),
    "rigs/x38.toml": (
        "x38",
        "the X-38-like article: 21 triaxes on DAQ inputs 1..63, the hammer on input 0 and\n"
        "# three load cells (nodes 3001..3003) on CAN node ids 1..3.",
    ),
    "rigs/cube.toml": (
        "cube-2",
        "the cube scenarios (cube-0.02, cube-2, cube-200): eight triaxes on DAQ inputs 1..24,\n"
        "# the hammer on input 0, no load cell.",
    ),
}


def certificate(true_value: float, serial: str) -> float:
    rng = np.random.default_rng([0xCE27, zlib.crc32(serial.encode("utf-8"))])
    return float(true_value * (1.0 + CERTIFICATE_ERROR * rng.standard_normal()))


def write_rig(name: str, scenario: str, header: str) -> None:
    built = build_scenario(scenario, None)
    lab = virtual_lab(built)
    setup = lab.model.setup
    acq = built.spec.acquisition
    path = CONFIG / name
    # calibration files live beside the rig file (a rig file may not point outside its folder)
    out = [
        "# Channel map of the acquisition rig (schema_version 1; see dimacq/io/rig_file.py) of",
        f"# {header}",
        "# Sensitivities are the calibration certificates' values (the simulated transducers differ",
        "# from their nominal 100 mV/g and 2.25 mV/N within ±5 %); written by",
        "# tests/scripts/simulated_rig_files.py. For a real rig, give your own.",
        "schema_version = 1",
        "",
        "[daq]",
        f"sample_rate_hz = {acq.sample_rate_hz}",
        "samples_per_frame = 256",
        'serial_number = ""        # "" = the first DAQ found (USB daq_vendor_id:daq_product_id)',
        "timeout_s = 5.0           # USB transfer timeout, s",
        "strike_timeout_s = 60.0   # how long the trigger waits for each strike, s",
        "",
        "[[hammers]]",
        "physical_channel = 0",
        "sensitivity_mv_per_n = "
        + f"{certificate(tr.true_sensitivity(tr.NOMINAL_HAMMER_MV_PER_N, tr.HAMMER_TOLERANCE, tr.hammer_serial(0)), tr.hammer_serial(0)):.4f}",
        "range_v = 5.0",
        "iepe_current_ma = 4.0",
        "inputs = []               # [] = this hammer strikes every input of the setup",
        "",
        "[acquisition]             # defaults of an impact test; a request's values win",
        f"record_samples = {acq.record_samples}",
        f"pretrigger_samples = {acq.pretrigger_samples}",
        "trigger_level_n = 5.0",
        f"averages_per_input = {acq.averages}",
        f"exponential_tau_s = {acq.exponential_tau_s}",
        "force_window_samples = 64",
    ]
    for i, lc in enumerate(setup.load_cells):
        cal = path.parent / "calibrations" / f"lc-{lc.node}.json"
        if (path.parent / "calibrations" / f"lc-{lc.node}-v1.json").exists():
            # the lab calibrated the cell on its bench since (``dimacq loadcell calibrate``,
            # installed as version 2): the certificate is its version 1
            cal = path.parent / "calibrations" / f"lc-{lc.node}-v1.json"
        S = lab.gauge_matrix(lc.node)
        rng = np.random.default_rng([0xCA1, lc.node])
        E = CERTIFICATE_ERROR * rng.standard_normal((6, 6))
        write_calibration_json(
            LoadCellCalibration(
                serial_number=str(lc.node),
                date="2026-11-23",
                matrix=(np.eye(6) + E) @ np.linalg.pinv(S),
                method="certificate",
                notes="simulated certificate (tests/scripts/simulated_rig_files.py)",
            ),
            cal,
        )
        out += [
            "",
            "[[load_cells]]",
            f"node = {lc.node}",
            f"node_id = {i + 1}",
            f'calibration_file = "calibrations/lc-{lc.node}.json"',
            'channel = ""              # "" = loadcell_channel of dimacq.toml',
        ]
        # its bridges on DAQ inputs after the accelerometers' (loadcell = "daq-channels")
        first = 1 + len(setup.responses) + 12 * i
        bridge = (lab.bridges or {}).get(lc.node)
        if first + 12 <= 64 and bridge is not None:
            out += [
                '# or its 12 bridges on DAQ inputs (loadcell = "daq-channels"):',
                f"daq_channels = [{', '.join(str(first + g) for g in range(12))}]",
                'daq_signals = "gauges"',
                f"excitation_v = {bridge.excitation_v:g}      # V; the calibration is in mV/V",
                "daq_range_v = 0.1",
                'daq_coupling = "DC"',
            ]
        out += [
            '# or an ATI Net F/T on it (loadcell = "netft-can" / "netft-can-simulated"):',
            f"netft_base = {0x020 + 8 * i:#05x}",
            "netft_counts_per_force = 1000000",
            "netft_counts_per_torque = 1000000",
            "netft_force_unit = 2",
            "netft_torque_unit = 3",
        ]
    for k, c in enumerate(setup.responses):
        ch = 1 + k
        serial = tr.accelerometer_serial(ch)
        true = tr.true_sensitivity(tr.NOMINAL_ACCEL_MV_PER_G, tr.ACCEL_TOLERANCE, serial)
        out += [
            "",
            "[[responses]]",
            f"node = {c.node}",
            f'direction = "{direction_label(c.direction)}"',
            f"physical_channel = {ch}",
            f"sensitivity_mv_per_g = {certificate(true, serial):.3f}",
            "range_v = 10.0",
            "iepe_current_ma = 4.0",
        ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    print(f"wrote {path}")


#: The scale the reference block is weighed on: standard uncertainty of one weighing, kg.
WEIGHING_U_KG = 0.005


def write_reference_block() -> None:
    """The reference block's drawing (a setup file) and its weighing certificate: what the lab
    knows of the body it calibrates its measurement chain on (``dimacq demo``'s first step,
    :mod:`dimacq.pipeline.chain_calibration`)."""
    from dimacq.io.setup_file import save_setup
    from dimacq.simulators.lab.forward import REFERENCE_BLOCK, reference_block_drawing

    folder = CONFIG / "reference-block"
    folder.mkdir(parents=True, exist_ok=True)
    save_setup(reference_block_drawing(), folder / "setup.toml")
    rng = np.random.default_rng([0x3E16, zlib.crc32(b"SIM-REF-BLOCK-1")])
    weighed = REFERENCE_BLOCK.mass_kg + WEIGHING_U_KG * rng.standard_normal()
    (folder / "mass.toml").write_text(
        "# Weighing certificate of the lab's reference block (solid aluminium, 0.32 x 0.28 x\n"
        "# 0.20 m, serial SIM-REF-BLOCK-1): the body of known mass the\n"
        "# measurement chain (hammer and accelerometers) is calibrated on (dimacq demo, step 0;\n"
        "# reference_mass of POST /api/solutions). Written by tests/scripts/simulated_rig_files.py.\n"
        "schema_version = 1\n"
        'serial_number = "SIM-REF-BLOCK-1"\n'
        f"mass_kg = {weighed:.4f}\n"
        f"u_kg = {WEIGHING_U_KG}            # standard uncertainty (k = 1)\n"
        'setup_file = "setup.toml"  # the drawing: sensor pockets, marked impact points, load cell\n',
        encoding="utf-8",
    )
    print(f"wrote {folder}")


def write_calibration_mass_setup(
    scenario: str = "calibration-mass-bungee",
    file_name: str = "calibration_mass_setup.toml",
    name: str = "calibration mass on load cell 501",
) -> None:
    """``config/calibration_mass_setup.toml``: the calibration mass on its cell as the lab states
    it (the scenario's setup) with its certificate under ``[known]`` (a machined steel block:
    mass, CG and inertia from its drawing and a weighing; here the article's values), read by
    the bench file's ``[inertial]`` table for the inertial calibration; and
    ``config/calibration_mass_on_cell.toml``: the same mass standing on the cell (scenario
    calibration-mass-ground, the cell underneath), ``check_setup_file`` of the circular check."""
    from dimacq.io.setup_file import save_setup
    from dimacq.model.setup import KnownProperties

    built = build_scenario(scenario, None)
    setup = built.setup
    props = built.truth
    P = np.asarray(setup.reference_point_m, float)
    I = props.inertia_about(P)
    names = {
        "Ixx": (0, 0),
        "Ixy": (0, 1),
        "Ixz": (0, 2),
        "Iyy": (1, 1),
        "Iyz": (1, 2),
        "Izz": (2, 2),
    }
    known = KnownProperties(
        mass_kg=float(props.mass_kg),
        cg_m=tuple(float(c) for c in props.cg_m),
        inertia_kgm2={k: float(I[i, j]) for k, (i, j) in names.items()},
    )
    path = CONFIG / file_name
    save_setup(setup.model_copy(update={"known": known, "name": name}), path)
    print(f"wrote {path}")


def main() -> None:
    for name, (scenario, header) in RIGS.items():
        write_rig(name, scenario, header)
    write_reference_block()
    write_calibration_mass_setup()
    write_calibration_mass_setup(
        "calibration-mass-ground",
        "calibration_mass_on_cell.toml",
        "calibration mass standing on load cell 501 (circular check)",
    )


if __name__ == "__main__":
    main()

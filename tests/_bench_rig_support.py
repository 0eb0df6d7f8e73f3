"""Test support: a rig folder for the load cell bench calibration (rig file + bench file).

Shared by the real-path service test and the HTTP test of calibration runs: the same rig (one
hammer on DAQ input 0, cell 501 on CAN node ``node_id``, its calibration file under
``calibrations/``) and the same fast dead-weight bench timing.
"""

from __future__ import annotations

from pathlib import Path

BENCH = """schema_version = 1
rated_load = [500.0, 500.0, 1000.0, 50.0, 50.0, 50.0]
plan = "minimal"
{points}[timing]
sample_rate_hz = 10
settle_s = 8.0
average_s = 2.0
max_wait_s = 20.0
"""

RIG = """schema_version = 1
[daq]
sample_rate_hz = 2048.0
[[hammers]]
physical_channel = 0
sensitivity_mv_per_n = 2.25
[[load_cells]]
node = 501
node_id = {node_id}
calibration_file = "calibrations/lc-501.json"
"""


def write_bench_rig(root: Path, *, node_id: int, points: str = "") -> Path:
    """Write ``root/rig/{rig.toml, loadcell_bench.toml}`` (and an empty ``calibrations/``);
    ``points`` is extra TOML (``[[points]]`` tables) for the bench file. Returns the rig folder."""
    rig_dir = root / "rig"
    (rig_dir / "calibrations").mkdir(parents=True)
    (rig_dir / "rig.toml").write_text(RIG.format(node_id=node_id), encoding="utf-8")
    (rig_dir / "loadcell_bench.toml").write_text(BENCH.format(points=points), encoding="utf-8")
    return rig_dir

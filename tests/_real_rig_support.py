"""The world behind a "real" rig for tests: simulators at the wire, found by configuration only.

:class:`VirtualWorld` builds a virtual lab (a scenario of ``config/scenarios``), the DAQ's SYNC
clock and one :class:`LoadCellAmplifierSim` per load cell listening on a python-can ``virtual``
channel with the node id of the rig file. While a world is :func:`installed`, the service finds
its DAQ through ``daq_backend = "_real_rig_support:daq_backend"`` — a plain pyusb backend factory
returning a :class:`VirtualDaqBackend` wired as the rig file says — and its amplifiers through
``loadcell_interface = "virtual"``. :meth:`VirtualWorld.strike` is the test operator's hand.
"""

from __future__ import annotations

import os
import time
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.io.loadcell_calibration import LoadCellCalibration, write_calibration_json
from dimacq.model.channels import gauge_names
from dimacq.model.frf import STANDARD_GRAVITY
from dimacq.model.setup import TestSetup, direction_label
from dimacq.simulators.daq.backend import DaqInput, VirtualDaqBackend
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.lab.impact import virtual_lab
from dimacq.simulators.lab.scenarios import build_scenario
from dimacq.simulators.loadcell.amplifier import LoadCellAmplifierSim
from dimacq.simulators.loadcell.bench import SupportSideBench

HAMMER_CH = 40  # the hammer is not on input 0: the map must come from the rig file
HAMMER_MV_PER_N = 2.25
ACCEL_MV_PER_G = 100.0


class PacedBackend(VirtualDaqBackend):
    """The DAQ simulator clocked in (scaled) real time, like a real DAQ: a bulk read returns a
    frame only once its last sample has been converted."""

    speed = 1.0

    def bulk_read(self, dev_handle: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        if self.running:
            if getattr(self, "_t0_run", None) is None or self._count == 0:
                self._t0_run = time.monotonic() - self._count / (self.sample_rate_hz * self.speed)
            due = self._t0_run + (self._count + self._spf) / (self.sample_rate_hz * self.speed)
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        return super().bulk_read(dev_handle, ep, intf, buff, timeout)


class VirtualWorld:
    """A scenario's article, its transducers and load cell amplifiers, for a subset setup.

    Parameters
    ----------
    scenario : str
    inputs : sequence of int
        Article inputs (indices) that the setup keeps.
    directory : Path
        Where the rig file and the calibration files are written.
    node_id : int
        CAN node id of the (first) amplifier.
    pace : float or None
        Run the DAQ clock at ``pace`` × real time (None: as fast as the host reads).
    bench_node : int or None
        The article is the calibration mass on the inertial bench of this load cell (struck on
        the cell's support side, :class:`~dimacq.simulators.loadcell.bench.SupportSideBench`).
    """

    def __init__(
        self,
        scenario: str,
        inputs: Sequence[int],
        directory: Path,
        *,
        node_id: int = 3,
        pace: float | None = None,
        seed: int = 0,
        bench_node: int | None = None,
    ) -> None:
        self.built = build_scenario(scenario, seed)
        self.lab = virtual_lab(self.built, hammer_noise=bench_node is None)
        self.source: Any = (
            self.lab if bench_node is None else SupportSideBench(self.lab, bench_node)
        )
        true = self.lab.model.setup
        self.inputs = list(inputs)
        self.setup = TestSetup(
            name=f"{scenario} (real rig test)",
            responses=true.responses,
            excitations=tuple(true.excitations[i] for i in self.inputs),
            load_cells=true.load_cells,
        )
        self.pace = pace
        self.clock = SampleClock()
        self.channel = f"dimacq-real-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        rng = np.random.default_rng(7)
        # Accelerometers on shuffled DAQ inputs 1..n (not in setup order).
        perm = rng.permutation(len(true.responses))
        self.wiring: dict[int, DaqInput] = {
            HAMMER_CH: DaqInput(self.lab.channel_index("hammer"), HAMMER_MV_PER_N * 1e-3)
        }
        self.response_ch: list[int] = []
        for k in range(len(true.responses)):
            ch = 1 + int(perm[k])
            self.response_ch.append(ch)
            self.wiring[ch] = DaqInput(k, ACCEL_MV_PER_G * 1e-3 / STANDARD_GRAVITY)
        self.sims: list[LoadCellAmplifierSim] = []
        self.node_ids: list[int] = []
        self.cal_files: list[Path] = []
        directory.mkdir(parents=True, exist_ok=True)
        try:
            for i, lc in enumerate(true.load_cells):
                gauges = [self.lab.channel_index(n) for n in gauge_names(lc.node)]
                nid = node_id + i
                self.sims.append(
                    LoadCellAmplifierSim(
                        self.channel,
                        self.source,
                        gauges,
                        clock=self.clock,
                        node_id=nid,
                        serial_number=lc.node,
                    )
                )
                self.node_ids.append(nid)
                cal = LoadCellCalibration(
                    serial_number=str(lc.node),
                    date="2024-05-01",
                    matrix=np.linalg.pinv(self.lab.gauge_matrix(lc.node)),
                )
                path = directory / f"lc-{lc.node}.json"
                write_calibration_json(cal, path)
                self.cal_files.append(path)
        except BaseException:
            self.close()
            raise
        self.rig_file = directory / "rig.toml"
        self.rig_file.write_text(self.rig_toml(), encoding="utf-8")
        self.backends: list[VirtualDaqBackend] = []
        self.strikes: list[tuple[int, int]] = []

    def rig_toml(self) -> str:
        acq = self.built.spec.acquisition
        out = [
            "schema_version = 1",
            "[daq]",
            f"sample_rate_hz = {acq.sample_rate_hz}",
            "samples_per_frame = 256",
            "timeout_s = 5.0",
            "strike_timeout_s = 30.0",
            "[[hammers]]",
            f"physical_channel = {HAMMER_CH}",
            f"sensitivity_mv_per_n = {HAMMER_MV_PER_N}",
            "range_v = 5.0",
            "inputs = []",
            "[acquisition]",
            f"pretrigger_samples = {acq.pretrigger_samples}",
            f"exponential_tau_s = {acq.exponential_tau_s}",
            "force_window_samples = 64",
        ]
        for c, ch in zip(self.lab.model.setup.responses, self.response_ch, strict=True):
            out += [
                "[[responses]]",
                f"node = {c.node}",
                f'direction = "{direction_label(c.direction)}"',
                f"physical_channel = {ch}",
                f"sensitivity_mv_per_g = {ACCEL_MV_PER_G}",
                "range_v = 10.0",
            ]
        for lc, nid, path in zip(
            self.lab.model.setup.load_cells, self.node_ids, self.cal_files, strict=True
        ):
            out += [
                "[[load_cells]]",
                f"node = {lc.node}",
                f"node_id = {nid}",
                f'calibration_file = "{path.name}"',
            ]
        return "\n".join(out) + "\n"

    def make_backend(self) -> VirtualDaqBackend:
        cls = VirtualDaqBackend
        if self.pace is not None:
            cls = type("PacedBackendX", (PacedBackend,), {"speed": self.pace})
        be = cls(self.source, self.wiring, clock=self.clock)
        self.backends.append(be)
        return be

    def strike(self, setup_input: int, margin_samples: int | None = None) -> None:
        """The operator's hand: strike setup input ``setup_input`` (0-based) a little after now."""
        margin = 2 * self.lab.block_samples if margin_samples is None else margin_samples
        with self.clock.source_lock:
            st = self.clock.state()
            at = st.epoch + st.count + margin
            self.source.excite(self.inputs[setup_input], at)
        self.strikes.append((setup_input, at))

    def close(self) -> None:
        while self.sims:
            self.sims.pop().close()


_WORLD: VirtualWorld | None = None


@contextmanager
def installed(world: VirtualWorld) -> Iterator[VirtualWorld]:
    """Make ``daq_backend = "_real_rig_support:daq_backend"`` find ``world``'s DAQ."""
    global _WORLD
    _WORLD = world
    try:
        yield world
    finally:
        _WORLD = None
        world.close()


def daq_backend() -> VirtualDaqBackend:
    """pyusb backend factory named in the settings (``daq_backend``)."""
    if _WORLD is None:
        raise RuntimeError("no virtual world installed")
    return _WORLD.make_backend()

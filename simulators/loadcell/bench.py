"""The inertial calibration bench of a 6-DOF load cell (method §8): struck on the support side.

On the bench the calibration mass hangs on its load cell exactly as in the DIM test, but the
hammer strikes a light, rigid fixture on the *support side* of the cell, so the cell carries every
force on the mass: the suspension's reaction and the whole hammer load. The motion of the mass is
the same as if it were struck directly at the same point and direction (the fixture is massless
and rigid), so the virtual lab's body dynamics are unchanged; what changes is the cell's reading.

:class:`SupportSideBench` wraps a :class:`~dimacq.simulators.lab.timedomain.VirtualLab` and adds
the transmitted hammer load to the gauges of one cell. For a strike of input ``j`` (point
``r_j``, direction ``d_j``, force ``f(t)``) the load on the body at the GCS origin is
``φ_j f = [d_j; r_j × d_j] f``; the cell's local load is ``F_L = (s T_c)⁻¹ φ_j f`` with
``T_c = [[R, 0], [[r_c]× R, R]]`` and ``s`` the cell's sign (+1 when it reads the load on the
structure), and its gauges read ``S F_L`` (S the 12×6 sensitivity). The lab's own gauges already
carry the suspension reaction, so in total ``g = S (s T_c)⁻¹ M_rb a_O`` at every instant
(Newton–Euler about O), the relation the calibration inverts.

The hammer force ``f(t)`` is the lab's hammer channel; give the lab ``force_noise_n = 0`` so the
transmitted load carries no hammer-transducer noise (the gauges keep their own noise and drift).
The strike that each hammer sample belongs to is the latest ``excite`` at or before it.
"""

from __future__ import annotations

import bisect

import numpy as np
from numpy.typing import NDArray

from dimacq.model.channels import gauge_names
from dimacq.simulators.lab.timedomain import VirtualLab

__all__ = ["SupportSideBench"]

FloatArray = NDArray[np.float64]


def _skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class SupportSideBench:
    """A :class:`~dimacq.simulators.lab.source.SampleSource`: the lab with load cell ``node``
    struck on its support side.

    Parameters
    ----------
    lab : VirtualLab
        The calibration mass on its cell (``force_noise_n`` should be 0, see the module docstring).
    node : int
        The load cell (support node) that carries the hammer load.
    """

    def __init__(self, lab: VirtualLab, node: int) -> None:
        supports = {s.node: s for s in lab.model.supports}
        if node not in supports:
            raise ValueError(f"the lab has no load cell {node}; it has {sorted(supports)}")
        if lab.noise.force_noise_n != 0.0:
            raise ValueError(
                "the bench transmits the hammer channel into the gauges: give the lab "
                "LabNoise(force_noise_n=0)"
            )
        self.lab = lab
        self.node = node
        self.sample_rate_hz = lab.sample_rate_hz
        self.channel_names = lab.channel_names
        self.channel_units = lab.channel_units
        s = supports[node]
        R = np.asarray(s.rotation, float)
        T = np.zeros((6, 6))
        T[:3, :3] = R
        T[3:, 3:] = R
        T[3:, :3] = _skew(np.asarray(s.position_m, float)) @ R
        sign = 1.0 if s.sign == "on_structure" else -1.0
        setup = lab.model.setup
        phi = np.concatenate(
            [setup.input_directions, np.cross(setup.input_positions, setup.input_directions)],
            axis=1,
        ).T  # (6, n_in)
        S = lab.gauge_matrix(node)
        #: gauge volts per newton of hammer force, per input: (12, n_in)
        self.transmission = S @ np.linalg.solve(sign * T, phi)
        self._gauges = np.array([lab.channel_index(n) for n in gauge_names(node)])
        self._gauge_pos = {int(c): g for g, c in enumerate(self._gauges)}
        self._hammer = lab.channel_index("hammer")
        self._strike_at: list[int] = []
        self._strike_input: list[int] = []

    @property
    def n_inputs(self) -> int:
        return self.lab.n_inputs

    def channel_index(self, name: str) -> int:
        return self.lab.channel_index(name)

    def gauge_matrix(self, node: int) -> FloatArray:
        return self.lab.gauge_matrix(node)

    def excite(self, input_index: int, at_sample: int) -> None:
        """Strike the fixture at input ``input_index``'s point from ``at_sample`` on."""
        self.lab.excite(input_index, at_sample)
        k = bisect.bisect_right(self._strike_at, at_sample)
        self._strike_at.insert(k, at_sample)
        self._strike_input.insert(k, input_index)

    def read(self, channels: NDArray[np.intp], start: int, n: int) -> FloatArray:
        ch = np.asarray(channels, dtype=np.intp)
        out = self.lab.read(ch, start, n)
        rows = np.flatnonzero(np.isin(ch, self._gauges))
        if rows.size == 0 or n <= 0 or not self._strike_at:
            return out
        force = self.lab.read(np.array([self._hammer]), start, n)[0]
        k = start + np.arange(n)
        which = np.searchsorted(np.asarray(self._strike_at), k, side="right") - 1
        struck = which >= 0
        inputs = np.where(struck, np.asarray(self._strike_input)[np.maximum(which, 0)], 0)
        gauge_of_row = np.array([self._gauge_pos[int(c)] for c in ch[rows]])
        # g_extra[r, t] = transmission[gauge(r), input(t)] · f(t)
        out[rows] += self.transmission[np.ix_(gauge_of_row, inputs)] * (force * struck)[None, :]
        return out

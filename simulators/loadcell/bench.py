"""The calibration benches of a 6-DOF load cell (method §8).

:class:`DeadWeightBench` — static calibration: the strain-gauge cell on a turnable fixture with a
loading arm; the operator hangs weights at the arm's points. :class:`SupportSideBench` — inertial
calibration: the calibration mass on its cell, struck on the support side.

Dead-weight bench
-----------------
The bench knows its own truth: each weight's true mass (the nominal one within its class
tolerance), each hanger point's true position (the digitized one plus a small error), the true
orientation of the cell (the nominal one tilted by a small levelling error) and the arm's own
weight. The load of ``m`` kg at point ``r`` with gravity ``d`` (cell frame) is
``[m g d; r × m g d]``; the arm adds ``[m_a g d; r_a × m_a g d]`` in every orientation (the
series' zero carries it). The bridges (:class:`~dimacq.simulators.lab.bridge.BridgeState`) turn
the load into mV/V with their hysteresis, creep, hanger swing, zero drift and noise; the
amplifier simulator reads the 12 gauge channels like any other :class:`SampleSource`.

Inertial bench
--------------

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
from dimacq.pipeline.rigid_body import skew
from dimacq.simulators.lab.bridge import BridgeState, StrainGaugeCell
from dimacq.simulators.lab.timedomain import VirtualLab

__all__ = ["DeadWeightBench", "SupportSideBench"]

FloatArray = NDArray[np.float64]


STANDARD_GRAVITY = 9.80665


class DeadWeightBench:
    """A :class:`~dimacq.simulators.lab.source.SampleSource`: one strain-gauge cell on the
    dead-weight bench (see the module docstring).

    Channels ``"LC{node} g01" .. "g12"`` (mV/V) and ``"LC{node} Fx" .. "Mz"`` (the true load, N
    and N·m, for tests).

    Parameters
    ----------
    cell : StrainGaugeCell
    node : int
    sample_rate_hz : float
    seed : int
        Noise and the bench's errors.
    mass_rel_error, position_error_m, tilt_error_rad : float
        Standard deviations of the true masses, hanger points and orientation about their
        nominal values.
    arm_mass_kg, arm_cg_m : float, (3,)
        The loading arm's own weight and centre of gravity (cell frame).
    """

    def __init__(
        self,
        cell: StrainGaugeCell,
        *,
        node: int = 501,
        sample_rate_hz: float = 50.0,
        seed: int = 0,
        mass_rel_error: float = 2e-5,
        position_error_m: float = 3e-6,
        tilt_error_rad: float = 5e-5,
        arm_mass_kg: float = 1.5,
        arm_cg_m: tuple[float, float, float] = (0.0, 0.0, 0.04),
    ) -> None:
        import threading

        self.cell = cell
        self.node = node
        self.sample_rate_hz = float(sample_rate_hz)
        self.channel_names = tuple(
            [f"LC{node} g{g + 1:02d}" for g in range(12)]
            + [f"LC{node} {q}" for q in ("Fx", "Fy", "Fz", "Mx", "My", "Mz")]
        )
        self.channel_units = tuple(["mV/V"] * 12 + ["N"] * 3 + ["N*m"] * 3)
        self.seed = seed
        self._rng = np.random.default_rng([seed, 97])
        self._mass_rel_error = mass_rel_error
        self._position_error_m = position_error_m
        self._tilt_error_rad = tilt_error_rad
        self._arm = (arm_mass_kg, np.asarray(arm_cg_m, float))
        self._true_points: dict[tuple[float, ...], FloatArray] = {}
        self._true_gravity: dict[tuple[float, ...], FloatArray] = {}
        self._true_mass: dict[float, float] = {}
        self.state = BridgeState(cell)
        self.applied: list[tuple[int, FloatArray]] = []  # (sample, true load) per placement
        self._frontier = 0
        self._lock = threading.Lock()

    @property
    def n_inputs(self) -> int:
        return 0

    def channel_index(self, name: str) -> int:
        return self.channel_names.index(name)

    def gauge_matrix(self, node: int) -> FloatArray:
        return np.asarray(self.cell.sensitivity_mvv, float)

    # -- truth of the bench ------------------------------------------------------------------
    def _point(self, nominal: FloatArray) -> FloatArray:
        key = tuple(np.round(nominal, 9))
        if key not in self._true_points:
            self._true_points[key] = nominal + self._rng.normal(
                scale=self._position_error_m, size=3
            )
        return self._true_points[key]

    def _gravity(self, nominal: FloatArray) -> FloatArray:
        key = tuple(np.round(nominal, 9))
        if key not in self._true_gravity:
            axis = self._rng.normal(size=3)
            axis -= (axis @ nominal) * nominal
            axis /= np.linalg.norm(axis)
            ang = self._tilt_error_rad * self._rng.standard_normal()
            d = nominal * np.cos(ang) + np.cross(axis, nominal) * np.sin(ang)
            self._true_gravity[key] = d / np.linalg.norm(d)
        return self._true_gravity[key]

    def _mass(self, nominal: float) -> float:
        if nominal not in self._true_mass:
            self._true_mass[nominal] = nominal * (1 + self._mass_rel_error * self._rng.normal())
        return self._true_mass[nominal]

    def true_load(self, mass_kg: float, position_m: FloatArray, gravity: FloatArray) -> FloatArray:
        """The true load (6,) of ``mass_kg`` nominal at the nominal point and orientation,
        the arm's own weight included."""
        d = self._gravity(np.asarray(gravity, float))
        r = self._point(np.asarray(position_m, float))
        m = self._mass(float(mass_kg)) if mass_kg else 0.0
        ma, ra = self._arm
        f = m * STANDARD_GRAVITY * d
        fa = ma * STANDARD_GRAVITY * d
        return np.concatenate([f + fa, np.cross(r, f) + np.cross(ra, fa)])

    # -- the operator --------------------------------------------------------------------------
    def place(
        self,
        mass_kg: float,
        position_m: FloatArray,
        gravity: FloatArray,
        at_sample: int = 0,
    ) -> int:
        """The operator sets up a load case (nominal values) from ``at_sample`` (or the first
        sample not yet read, if later); returns the sample it took effect."""
        with self._lock:
            k = max(int(at_sample), self._frontier)
            load = self.true_load(mass_kg, position_m, gravity)
            self.state.place(load, k / self.sample_rate_hz)
            self.applied.append((k, load))
            return k

    def excite(self, input_index: int, at_sample: int) -> None:
        raise ValueError("the dead-weight bench has no hammer inputs; place() weights instead")

    def read(self, channels: NDArray[np.intp], start: int, n: int) -> FloatArray:
        ch = np.asarray(channels, dtype=np.intp)
        with self._lock:
            self._frontier = max(self._frontier, start + n)
            k = start + np.arange(n)
            t = k / self.sample_rate_hz
            rng = np.random.default_rng([self.seed, 31, start, n])
            g = self.state.readings(t, rng=rng)
            times = np.array([-np.inf] + [a / self.sample_rate_hz for a, _ in self.applied])
            loads = np.stack([np.zeros(6)] + [ld for _, ld in self.applied])
            which = np.searchsorted(times, t, side="right") - 1
            allc = np.concatenate([g, loads[which].T])
            return np.asarray(allc[ch], dtype=np.float64)


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
        T[3:, :3] = skew(np.asarray(s.position_m, float)) @ R
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

    @property
    def frontier(self) -> int:
        """The lab's first sample not yet generated (a free-running DAQ strikes no earlier)."""
        return self.lab.frontier

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

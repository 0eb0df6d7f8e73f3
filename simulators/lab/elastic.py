"""Global elastic modes of a slender hull: vertical bending, torsion and lateral bending.

The shipped X-38-like vehicle has local elastic modes (a drogue-chute pack, the twin tails); a
large, light or built-up structure also deforms as a whole. These generators give the first
free-free mode of each kind of a hull lying along X between ``x0`` and ``x0 + L``:

- bending in a plane (the uniform free-free beam, ``βL = 4.730041``,
  ``σ = (cosh βL − cos βL)/(sinh βL − sin βL)``):
  ``w(x) = cosh βx + cos βx − σ (sinh βx + sin βx)``, ``|w| ≤ 2`` (at the ends); vertical
  bending moves node n by ``u_z = w(x_n)``, ``θ_y = −w'(x_n)``; lateral bending by
  ``u_y = w(x_n)``, ``θ_z = w'(x_n)``;
- torsion about the line ``y = 0, z = z_axis`` (first free-free torsion of a uniform shaft):
  ``θ_x(x) = cos(π x / L)``, so a node at ``(y, z)`` moves ``u = θ_x e_x × (r − r_axis)``:
  ``u_y = −θ_x (z − z_axis)``, ``u_z = θ_x y``.

Scaling ("modal mass a fraction of the structure's"): each shape ``φ`` is scaled to a largest
nodal translation of 1 over the listed nodes, and its modal mass in that scaling is
``μ = fraction · m`` (e.g. one fifth of the vehicle's 8 089 kg); the mass-normalised shape the
forward model takes is ``ψ = φ / √μ``. The forward model treats every mode as orthogonal to the
rigid-body motion (free-free modes are), so the body's ten properties stay the truth.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError
from dimacq.simulators.lab.forward import FlexibleMode

__all__ = ["hull_modes"]

FloatArray = NDArray[np.float64]

_BETA_L = 4.730040744862704


def _beam(x: FloatArray, length_m: float) -> tuple[FloatArray, FloatArray]:
    """``w(x)`` and ``w'(x)`` (1/m) of the first free-free bending mode, ``x`` clipped to [0, L]."""
    b = _BETA_L / length_m
    sigma = (np.cosh(_BETA_L) - np.cos(_BETA_L)) / (np.sinh(_BETA_L) - np.sin(_BETA_L))
    x = np.clip(x, 0.0, length_m)
    w = np.cosh(b * x) + np.cos(b * x) - sigma * (np.sinh(b * x) + np.sin(b * x))
    dw = b * (np.sinh(b * x) - np.sin(b * x) - sigma * (np.cosh(b * x) + np.cos(b * x)))
    return w, dw


def hull_modes(
    frequencies_hz: Sequence[float],
    *,
    mass_kg: float,
    nodes: Mapping[int, FloatArray],
    x_range_m: tuple[float, float],
    z_axis_m: float,
    modal_mass_fraction: float = 0.2,
    damping_ratio: float = 0.02,
) -> tuple[FlexibleMode, ...]:
    """Vertical bending, torsion and lateral bending of a hull, in that order.

    Parameters
    ----------
    frequencies_hz : (f_bending, f_torsion, f_lateral), Hz
    mass_kg : float
        The structure's mass; each mode's modal mass (unit peak translation) is
        ``modal_mass_fraction · mass_kg``.
    nodes : mapping node -> (3,) position, m
        Every node that moves (responses, inputs, load cells).
    x_range_m : (x0, x1)
        The hull's extent along X.
    z_axis_m : float
        Height of the torsion axis, m.
    """
    f = [float(v) for v in frequencies_hz]
    if len(f) != 3 or not all(v > 0 for v in f):
        raise SetupError(
            f"elastic_modes_hz = {list(frequencies_hz)}; give three positive frequencies in Hz "
            "(bending, torsion, lateral)"
        )
    if not 0 < modal_mass_fraction <= 1:
        raise SetupError(
            f"elastic_modal_mass_fraction = {modal_mass_fraction}; give a fraction in (0, 1]"
        )
    ids = [int(n) for n in nodes]
    pos = np.array([np.asarray(nodes[n], float) for n in ids]).reshape(-1, 3)
    x0, x1 = x_range_m
    w, dw = _beam(pos[:, 0] - x0, x1 - x0)
    zero = np.zeros(len(ids))
    theta = np.cos(np.pi * (np.clip(pos[:, 0], x0, x1) - x0) / (x1 - x0))
    shapes = {
        "hull vertical bending": np.stack([zero, zero, w, zero, -dw, zero], axis=1),
        "hull torsion": np.stack(
            [zero, -theta * (pos[:, 2] - z_axis_m), theta * pos[:, 1], theta, zero, zero], axis=1
        ),
        "hull lateral bending": np.stack([zero, w, zero, zero, zero, dw], axis=1),
    }
    mu = modal_mass_fraction * mass_kg
    out = []
    for (name, phi), f_hz in zip(shapes.items(), f, strict=True):
        peak = float(np.max(np.linalg.norm(phi[:, :3], axis=1)))
        psi = phi / (peak * np.sqrt(mu))
        out.append(FlexibleMode(name, f_hz, damping_ratio, {n: psi[k] for k, n in enumerate(ids)}))
    return tuple(out)

"""Weighing certificate of a reference body (``config/reference-block/mass.toml``).

The body of known mass a lab calibrates its measurement chain on
(:mod:`dimacq.pipeline.chain_calibration`): its serial number, weighed mass and the weighing's
standard uncertainty, and the setup file of its drawing (sensor pockets, marked impact points).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from dimacq.errors import SetupError

__all__ = ["ReferenceMass", "load_reference_mass"]


@dataclass(frozen=True)
class ReferenceMass:
    """A weighed reference body.

    Attributes
    ----------
    serial_number : str
    mass_kg : float
        Weighed mass, kg.
    u_kg : float
        Standard uncertainty of the weighing (k = 1), kg.
    setup_file : Path or None
        The body's drawing as a setup file (absolute), if the certificate names one.
    """

    serial_number: str
    mass_kg: float
    u_kg: float
    setup_file: Path | None = None


def load_reference_mass(path: str | Path) -> ReferenceMass:
    """Read and check a weighing certificate (``schema_version = 1``).

    Raises
    ------
    SetupError
        Missing file, bad TOML, or a value out of range (the message names the key).
    """
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise SetupError(
            f"reference mass file {p.name}: not found; give the certificate's path"
        ) from err
    except tomllib.TOMLDecodeError as err:
        raise SetupError(f"reference mass file {p.name}: not TOML ({err})") from err
    if doc.get("schema_version") != 1:
        raise SetupError(f"reference mass file {p.name}: schema_version must be 1")
    try:
        mass = float(doc["mass_kg"])
        u = float(doc["u_kg"])
    except (KeyError, TypeError, ValueError) as err:
        raise SetupError(
            f"reference mass file {p.name}: give mass_kg and u_kg as numbers in kg ({err})"
        ) from err
    if not (math.isfinite(mass) and mass > 0):
        raise SetupError(f"reference mass file {p.name}: mass_kg {mass} must be > 0 (kg)")
    if not (math.isfinite(u) and 0 <= u < mass):
        raise SetupError(f"reference mass file {p.name}: u_kg {u} must be ≥ 0 and < mass_kg (kg)")
    setup = doc.get("setup_file")
    return ReferenceMass(
        serial_number=str(doc.get("serial_number", "")),
        mass_kg=mass,
        u_kg=u,
        setup_file=(p.parent / str(setup)).resolve() if setup else None,
    )

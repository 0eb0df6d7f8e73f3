"""Setup files: one :class:`~dimacq.model.setup.TestSetup` in TOML or JSON.

The format is chosen by the extension: ``.toml`` (read with :mod:`tomllib`, written with
``tomli_w``) or ``.json``. Both hold the same keys; unknown keys are refused (a misspelt key would
otherwise be silently ignored). Errors raise :class:`~dimacq.errors.SetupError` naming the file,
the item (e.g. ``responses[3].direction_gcs``) and the fix.

Format (schema_version 1)
-------------------------
All coordinates are in the global coordinate system (GCS) of the structure, in **metres**;
directions are **unit vectors** in the GCS (length 1 within 1e-6).

Top level
    ``schema_version`` : int, required value 1 (default 1).
    ``name`` : str, free text (default "").
    ``reference_point_m`` : [x, y, z] m, the point P about which the inertia is reported
    (default [0, 0, 0]).
    ``length_unit`` : "m" | "cm" | "mm", the unit the solver works in internally; it weights moment
    rows against force rows (default "m"). The file itself is always in metres.

``[[responses]]`` (one table per accelerometer axis, at least 6, each node/direction once)
    ``node`` : int, node number (as in UFF).
    ``direction`` : int, UFF direction of the axis in the node's own system, ±1, ±2 or ±3.
    ``position_m`` : [x, y, z] m, the measurement point.
    ``direction_gcs`` : [dx, dy, dz], unit vector of the measured (positive) direction.
    ``label`` : str, optional (default "" → ``"<node><±axis>"``, e.g. ``1+X``).

``[[inputs]]`` (one table per input, each node/direction once; ``[[excitations]]`` in the first
setup files, still read with a deprecation message)
    ``node`` : int; ``direction`` : int, UFF reference direction ±1..±3 (default 1);
    ``position_m`` : [x, y, z] m, point of application;
    ``direction_gcs`` : [dx, dy, dz], unit line of action (direction of a positive force on the
    structure), required; ``label`` : str, optional.

``[[load_cells]]`` (optional, 6-DOF load cells between the structure and its supports)
    ``node`` : int, node number of the cell (its FRFs use directions 1–6 = Fx, Fy, Fz, Mx, My, Mz
    in the cell's system).
    ``position_m`` : [x, y, z] m, origin of the cell's measuring system.
    ``rotation`` : 3×3 nested list, local-to-global rotation R (``x_G = R x_L``); **column** k is
    the cell's local axis k in the GCS (proper rotation, det +1). Default: identity.
    ``sign`` : "on_structure" (outputs are the load the support exerts on the structure, the DIM
    convention) | "on_support" (the load on the support; dimacq negates it). Default "on_structure".
    ``label`` : str, optional.

``[known]`` (optional, properties known beforehand; any subset, keyed by the ten parameter names
of ``dimacq solve`` and the API)
    ``m`` : mass, kg > 0.
    ``cx``, ``cy``, ``cz`` : the CG in the GCS, m (unknown components left out).
    ``Ixx``, ``Ixy``, ``Ixz``, ``Iyy``, ``Iyz``, ``Izz`` : kg·m², tensor elements about the
    reference point (products of inertia carry the tensor sign, ``Ixy = −∫xy dm``).
    The first setup files wrote ``mass_kg``, ``cg_m`` (a list, or a table of ``x``, ``y``, ``z``)
    and ``inertia_kgm2`` (a table): still read, with a deprecation message.

``[geometry_uncertainty]`` (optional; standard uncertainties, 1σ, of the geometry above)
    ``sensor_position_m`` (default 0.002), ``sensor_orientation_deg`` (0.5), ``input_position_m``
    (0.002), ``line_of_action_deg`` (1.0), ``load_cell_position_m`` (0.002) and
    ``load_cell_orientation_deg`` (0.5, each load cell's pose: the output-error fit refines it);
    ``registration_rms_m`` and ``registration_limit_m``
    (written by a digitized setup); ``source`` = "default" | "stated" | "digitized". They widen
    the 95 % intervals, act as priors where the geometry is refined, and enter the verdict.

``[transducer_uncertainty]`` (optional; relative 1σ of the certificate sensitivities)
    ``accel_sensitivity_rel`` (default 0.005, each axis independently), ``force_sensitivity_rel``
    (0.005, one value for the hammer, common to all inputs); ``source`` = "default" | "stated".
    The force transducer's error scales mass and inertia directly: it sets a floor on their
    intervals that only a known mass (``--scale-to-mass``) removes.

Example (TOML)::

    schema_version = 1
    name = "bracket"
    reference_point_m = [0.0, 0.0, 0.0]
    length_unit = "m"

    [[responses]]
    node = 1
    direction = 1
    position_m = [0.10, 0.05, 0.02]
    direction_gcs = [1.0, 0.0, 0.0]

    [[inputs]]
    node = 21
    direction = 1
    position_m = [0.20, 0.0, 0.05]
    direction_gcs = [0.0, 0.0, 1.0]

    [[load_cells]]
    node = 501
    position_m = [0.0, 0.0, -0.06]
    rotation = [[0.7071067811865476, -0.7071067811865476, 0.0],
                [0.7071067811865476,  0.7071067811865476, 0.0],
                [0.0, 0.0, 1.0]]
    sign = "on_structure"

    [known]
    m = 3.2
    cz = 0.01

A complete example with six triaxial accelerometers is bundled as
``config/examples/six_triax_setup.toml``.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any, BinaryIO, Literal

import tomli_w
from pydantic import ValidationError

from dimacq.errors import SetupError
from dimacq.io.documents import loads_json, loads_toml
from dimacq.model.setup import TestSetup

__all__ = [
    "SUFFIXES",
    "dump_setup_dict",
    "load_setup",
    "parse_setup",
    "read_setup",
    "save_setup",
]

logger = logging.getLogger(__name__)

#: File name extensions understood by :func:`load_setup` and :func:`save_setup`.
SUFFIXES = (".toml", ".json")

_AXES = ("x", "y", "z")

# Fixes suggested for pydantic error types whose message does not say what to do.
_FIXES: dict[str, str] = {
    "missing": "add this key",
    "extra_forbidden": "remove this key or correct its spelling",
    "float_parsing": "give a number",
    "float_type": "give a number",
    "int_parsing": "give an integer",
    "int_type": "give an integer",
    "int_from_float": "give an integer",
    "tuple_type": "give a list",
    "too_short": "give exactly 3 numbers (x, y, z)",
    "too_long": "give exactly 3 numbers (x, y, z)",
    "literal_error": "use one of the values listed",
    "string_type": "give a text string",
    "greater_than": "give a positive value",
    "greater_than_equal": "give a value inside the range",
    "less_than_equal": "give a value inside the range",
    "dict_type": "give a table",
    "model_type": "give a table",
}


def _loc(loc: tuple[str | int, ...]) -> str:
    """Pydantic location tuple → ``responses[3].direction_gcs``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def _describe(err: ValidationError, source: str) -> str:
    lines = []
    for e in err.errors(include_url=False):
        msg = str(e["msg"]).removeprefix("Value error, ")
        fix = _FIXES.get(str(e["type"]), "")
        loc = tuple(e["loc"])
        if e["type"] == "missing" and loc and isinstance(loc[-1], int):
            # a fixed-length vector with too few items: pydantic names the missing index
            msg = f"has too few items (item {loc[-1]} is missing)"
            fix = "give exactly 3 numbers (x, y, z); a rotation is 3 rows of 3 numbers"
            loc = loc[:-1]
        where = _loc(loc)
        lines.append(f"{source}: {where}: {msg}" + (f"; {fix}" if fix and ";" not in msg else ""))
    return "\n".join(lines)


def _known_from_file(known: Any, source: str) -> Any:
    """Old ``cg_m`` tables ``{x, y, z}`` checked here, so the message names the file."""
    cg = known.get("cg_m") if isinstance(known, Mapping) else None
    if isinstance(cg, Mapping):
        extra = set(cg) - set(_AXES)
        if extra:
            raise SetupError(
                f"{source}: known.cg_m has unknown key(s) {sorted(extra)}; use x, y and/or z "
                "(better: the parameter names cx, cy, cz)"
            )
    return known


def parse_setup(data: Mapping[str, Any], source: str = "<setup>") -> TestSetup:
    """Validate a setup given as a mapping (the parsed file) into a :class:`TestSetup`.

    Raises
    ------
    SetupError
        One line per problem: ``<source>: <item>: <what is wrong>; <fix>``.
    """
    if not isinstance(data, Mapping):
        raise SetupError(
            f"{source}: the top level must be a table of keys, not {type(data).__name__}"
        )
    data = dict(data)
    if "known" in data:
        data["known"] = _known_from_file(data["known"], source)
    if "excitations" in data:
        if "inputs" in data:
            raise SetupError(
                f"{source}: both inputs and excitations are given; keep inputs (excitations is "
                "its old name)"
            )
        logger.warning(
            "%s: [[excitations]] is the old name of [[inputs]] (read as such); rename it", source
        )
    try:
        return TestSetup.model_validate(data)
    except ValidationError as err:
        raise SetupError(_describe(err, source)) from err


def read_setup(
    data: bytes | BinaryIO, fmt: Literal["toml", "json"], source: str = "uploaded setup"
) -> TestSetup:
    """Read a setup document from bytes or a binary stream (``fmt`` ``toml`` or ``json``).

    ``source`` names the document in messages (a file name, or "uploaded setup": never a server
    path the user did not give).

    Raises
    ------
    SetupError
        Not UTF-8, not valid TOML/JSON, not a table/object, or an item is wrong (the message names
        the source, the item such as ``responses[3].direction_gcs`` and the fix).
    """
    raw = data if isinstance(data, bytes) else data.read()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise SetupError(f"{source}: not UTF-8 text ({err}); save it as UTF-8") from err
    # within the documents' limits (size, depth, values, digits): refused with the limit named
    doc = loads_toml(text, source) if fmt == "toml" else loads_json(text, source)
    if not isinstance(doc, Mapping):
        raise SetupError(
            f"{source}: the setup must be a JSON object (or TOML table) with responses and inputs"
        )
    return parse_setup(doc, source)


def load_setup(path: str | Path) -> TestSetup:
    """Read a setup file (``.toml`` or ``.json``, format in the module docstring).

    Raises
    ------
    SetupError
        The file is missing or unreadable, not valid TOML/JSON, or an item is wrong (the message
        names the file, the item such as ``responses[3].direction_gcs`` and the fix).
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise SetupError(f"{p}: unknown setup file type {p.suffix!r}; use a .toml or .json file")
    try:
        raw = p.read_bytes()
    except OSError as err:
        raise SetupError(
            f"{p}: cannot read the setup file ({err.strerror}); check the path"
        ) from err
    setup = read_setup(raw, "toml" if suffix == ".toml" else "json", str(p))
    logger.debug(
        "read setup %s: %d responses, %d excitations, %d load cells",
        p,
        len(setup.responses),
        len(setup.excitations),
        len(setup.load_cells),
    )
    return setup


def dump_setup_dict(setup: TestSetup, *, toml: bool = False) -> dict[str, Any]:
    """The setup as plain data in the file format (no nulls: unknown properties left out)."""
    data: dict[str, Any] = setup.model_dump(mode="json", exclude_none=True, by_alias=True)
    if not data.get("known"):
        data.pop("known", None)
    return data


def save_setup(setup: TestSetup, path: str | Path) -> None:
    """Write a setup file (``.toml`` or ``.json`` by extension) that :func:`load_setup` reads back
    to an equal :class:`TestSetup` (floats are written with full precision)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise SetupError(f"{p}: unknown setup file type {p.suffix!r}; use a .toml or .json file")
    if suffix == ".toml":
        text = tomli_w.dumps(dump_setup_dict(setup, toml=True))
    else:
        text = json.dumps(dump_setup_dict(setup), indent=2) + "\n"
    try:
        p.write_text(text, encoding="utf-8")
    except OSError as err:
        raise SetupError(
            f"{p}: cannot write the setup file ({err.strerror}); check the path"
        ) from err

"""Channel names: one place for how a response, an input and a load cell's channels are called.

Every layer (the virtual lab's sample source, the simulators, the rig file, the acquisition
session, the CLI) names channels with these functions, so a name built in one place is found in
another:

- a response or input axis: ``"1103+Y"`` (:func:`axis_name`: node, then the UFF direction label);
- a struck input in messages: ``"117+Z"`` (:func:`input_name`: node, then the GCS axis its line of
  action lies along, whatever UFF direction the setup records for it);
- a load cell's gauges: ``"LC501 g01" .. "LC501 g12"`` (:func:`gauge_names`, :data:`N_GAUGES`);
- a load cell's six loads in its frame: ``"LC501 Fx" .. "LC501 Mz"`` (:func:`load_names`,
  :data:`LOAD_AXES`; UFF directions 1..6 in that order).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from dimacq.model.setup import Excitation, direction_label

__all__ = [
    "AXIS_NAME_TOLERANCE_DEG",
    "LOAD_AXES",
    "N_GAUGES",
    "axis_name",
    "gauge_name",
    "gauge_names",
    "input_name",
    "load_names",
    "loadcell_prefix",
]

#: Strain gauges of a 6-DOF load cell (three per spoke, four spokes).
N_GAUGES = 12

#: A load cell's loads in its frame, UFF directions 1..6: forces (N), then moments (N·m).
LOAD_AXES: tuple[str, ...] = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")


def axis_name(node: int, direction: int) -> str:
    """``"1103+Y"``: a response or input axis (node and UFF direction ±1..±3)."""
    return f"{node}{direction_label(direction)}"


#: Largest angle between an input's line of action and a GCS axis for the input to be named by that
#: axis (``"117+Z"``); a line further off every axis is named by its direction cosines.
AXIS_NAME_TOLERANCE_DEG = 20.0


def input_name(excitation: Excitation) -> str:
    """``"117+Z"``: an input named by its point and the GCS axis of its line of action.

    With ``d`` the unit line of action in the GCS (``direction_gcs``) and ``k = argmax |d_k|``,
    the name is the node, the sign of ``d_k`` and axis ``k`` when the angle ``arccos |d_k|`` to
    that axis is at most :data:`AXIS_NAME_TOLERANCE_DEG`; otherwise the node and ``d`` to two
    decimals (``"117(+0.71,+0.00,-0.71)"``). The UFF direction the setup records is a label in
    the node's system (an input struck along +Z can carry direction 1): it is what channel keys
    are built from (:func:`axis_name`), not what the operator strikes along.
    """
    d: Sequence[float] | None = excitation.direction_gcs
    if d is None:
        return axis_name(excitation.node, excitation.direction)
    k = max(range(3), key=lambda i: abs(d[i]))
    if math.degrees(math.acos(min(1.0, abs(d[k])))) <= AXIS_NAME_TOLERANCE_DEG:
        return f"{excitation.node}{'+' if d[k] > 0 else '-'}{'XYZ'[k]}"
    return f"{excitation.node}(" + ",".join(f"{x:+.2f}" for x in d) + ")"


def loadcell_prefix(node: int) -> str:
    """``"LC501"``: what every channel of load cell ``node`` starts with."""
    return f"LC{node}"


def gauge_name(node: int, gauge: int) -> str:
    """``"LC501 g03"``: gauge ``gauge`` (0-based) of load cell ``node``."""
    if not 0 <= gauge < N_GAUGES:
        raise ValueError(f"gauge {gauge} is not 0..{N_GAUGES - 1}")
    return f"{loadcell_prefix(node)} g{gauge + 1:02d}"


def gauge_names(node: int) -> list[str]:
    """The :data:`N_GAUGES` gauge channels of load cell ``node`` in order."""
    return [gauge_name(node, g) for g in range(N_GAUGES)]


def load_names(node: int) -> list[str]:
    """The six load channels of load cell ``node`` (``"LC501 Fx" .. "LC501 Mz"``)."""
    return [f"{loadcell_prefix(node)} {q}" for q in LOAD_AXES]

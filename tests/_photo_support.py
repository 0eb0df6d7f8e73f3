"""A small rendered photo set for the photo-geometry job's tests: the simulated calibration mass
with two of its triaxes and one input tagged (the lab's standard tag plan), photographed by the
simulated camera; the setup of those triaxes and that input, and the simulator's truth."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.io.setup_file import dump_setup_dict
from dimacq.io.tags_file import dump_tags, standard_tags
from dimacq.simulators.camera.render import photograph_article, tagged_world
from dimacq.simulators.lab.scenarios import build_scenario

__all__ = ["PhotoSet", "small_photo_set"]


@dataclass(frozen=True)
class PhotoSet:
    folder: Path  # the photos and tags.toml
    setup: dict[str, Any]  # setup-file keys: the two triaxes and the input
    full_setup: dict[str, Any]  # every triax and input of the article (two tagged only)
    truth: dict[str, tuple[np.ndarray, np.ndarray]]  # body label → (R, position)
    nodes: list[int]
    inputs: list[int]


def small_photo_set(
    folder: Path, n_photos: int = 18, seed: int = 0, *, exif: bool = True
) -> PhotoSet:
    """Photos of two tagged triaxes and one tagged input of the calibration mass in ``folder``
    (with its ``tags.toml``); ``exif=False``: JPEGs without EXIF, as a camera file needs."""
    built = build_scenario("calibration-mass-bungee", seed)
    st = built.model.setup
    nodes = sorted({c.node for c in st.responses})[:2]
    inputs = [st.excitations[0].node]
    plan = standard_tags(nodes, inputs, np.vstack([st.response_positions, st.input_positions]))
    world = tagged_world(plan, st, np.random.default_rng(seed + 2000))
    photograph_article(world, folder, n_photos, seed + 3000, exif=exif)
    dump_tags(plan, folder / "tags.toml")
    full = dump_setup_dict(built.setup)
    small = dict(full)
    small["responses"] = [c for c in full["responses"] if c["node"] in nodes]
    small["inputs"] = [e for e in full["inputs"] if e["node"] in inputs]
    small["name"] = "calibration mass, two triaxes photographed"
    return PhotoSet(folder, small, full, world.truth, nodes, inputs)

"""The lab's standard tags on a built scenario's true article: the world the simulated camera
photographs (for ``dimacq demo --geometry photos`` and the photo-geometry studies)."""

from __future__ import annotations

import numpy as np

from dimacq.io.tags_file import TagsFile, standard_tags
from dimacq.simulators.camera.render import TaggedWorld, tagged_world
from dimacq.simulators.lab.scenarios import BuiltScenario

__all__ = ["tagged_scenario"]

#: articles whose triax blocks sit on the faces of a solid body, which hides what lies behind it
SOLID_ARTICLES = ("calibration-mass", "reference-block")


def tagged_scenario(
    built: BuiltScenario, *, exact_tags: bool = False
) -> tuple[TagsFile, TaggedWorld]:
    """``(plan, world)``: the standard tags plan (:func:`~dimacq.io.tags_file.standard_tags`)
    for the article's triaxes and inputs, and those tags on the true article
    (:func:`~dimacq.simulators.camera.render.tagged_world`, placements drawn from
    ``built.seed + 2000``). On a solid article the occluding body is the box between its
    sensors, 15 mm inside them. ``exact_tags``: the world's tags sit exactly where the plan
    puts them (the plan still states its placement 1σ)."""
    st = built.model.setup
    nodes = sorted({ch.node for ch in st.responses})
    ins = [e.node for e in st.excitations]
    plan = standard_tags(nodes, ins, np.vstack([st.response_positions, st.input_positions]))
    box = None
    if built.spec.article.model in SOLID_ARTICLES:
        r = st.response_positions
        box = (r.min(axis=0) + 0.015, r.max(axis=0) - 0.015)
    placed = plan
    if exact_tags:
        placed = plan.model_copy(update={"placement_angle_deg": 0.0, "placement_position_m": 0.0})
    return plan, tagged_world(placed, st, np.random.default_rng(built.seed + 2000), box)

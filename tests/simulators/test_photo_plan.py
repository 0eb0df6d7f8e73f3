"""The simulated photographer's plan: close-ups from between a body's visible faces, each
triax block seen through at least two of its tags together with another tagged body in the
rendered photos, rounds fair to every block, the camera sized to the article."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from dimacq.services.geometry.photo_geometry import detect_tags
from dimacq.simulators.camera.render import (
    FLOOR_Z,
    HIDDEN,
    PHONE_12MP,
    TRIAX_VIEWS,
    CameraModel,
    TaggedWorld,
    _between_faces,
    _round,
    camera_for,
    photo_plan,
    render,
)
from dimacq.simulators.camera.scenario import tagged_scenario
from dimacq.simulators.lab.scenarios import build_scenario

# a cube block mounted by its +y face: the visible faces' outward normals
_FACES = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])
_AWAY = np.array([0.0, -1.0, 0.0])


def test_close_up_directions_show_two_or_three_faces() -> None:
    dirs = _between_faces(_FACES, _AWAY, lambda _u: 0)
    assert len(dirs) >= 3
    for d in dirs:
        assert np.isclose(np.linalg.norm(d), 1.0)
        assert d[2] >= FLOOR_Z
        assert np.dot(d, _AWAY) > -0.2  # never from behind the mounting face
        cos_inc = _FACES @ d
        # every face it shows within 55° of square on, and two or three of them
        assert 2 <= int(np.sum(cos_inc > np.cos(np.radians(55.0)) - 1e-9)) <= 3
    # the side faces are seen from both sides over the plan's directions
    assert max(d[0] for d in dirs) > 0.4 and min(d[0] for d in dirs) < -0.4


def test_close_up_directions_avoid_what_hides_the_body() -> None:
    def blockers(u: np.ndarray) -> int:
        if u[0] > 0.1:
            return HIDDEN  # the article on that side
        return 1 if u[2] > 0.6 else 0  # a neighbour standing above it

    dirs = _between_faces(_FACES, _AWAY, blockers)
    assert dirs
    assert all(d[0] <= 0.1 and d[2] <= 0.6 for d in dirs)


def test_rounds_fair_to_every_block() -> None:
    names = [f"triax {k}" for k in range(5)] + [f"input {k}" for k in range(7)]
    r = _round(names, np.random.default_rng(3))
    counts = Counter(r)
    assert all(counts[f"triax {k}"] == TRIAX_VIEWS for k in range(5))
    assert all(counts[f"input {k}"] == 1 for k in range(7))
    for cut in range(1, len(r) + 1):  # a set cut short: no block more than one ahead
        c = Counter(n for n in r[:cut] if n.startswith("triax"))
        seen = [c[f"triax {k}"] for k in range(5)]
        assert max(seen) - min(seen) <= 1


def _world(scenario: str, seed: int) -> TaggedWorld:
    return tagged_scenario(build_scenario(scenario, seed))[1]


def test_camera_sized_to_the_article() -> None:
    assert camera_for(_world("calibration-mass-bungee", 0)) == CameraModel()
    assert camera_for(_world("x38", 0)) == PHONE_12MP


@pytest.mark.parametrize("seed", [5, 6])
def test_triax_close_ups_show_two_tags_and_a_neighbour(seed: int) -> None:
    world = _world("calibration-mass-bungee", seed)
    cam = camera_for(world)
    body_of = {t.tag_id: t.body for t in world.tags}
    centre = {
        b: np.mean([t.centre_m for t in world.tags if t.body == b], axis=0)
        for b in set(body_of.values())
    }
    rng = np.random.default_rng(seed)
    two, other, n = 0, 0, 0
    for shot in photo_plan(world, 36, seed + 3000):
        if shot.kind != "close-up" or not str(shot.body).startswith("triax"):
            continue
        eye = -shot.r_wc.T @ shot.t_wc
        view = (eye - centre[shot.body]) / np.linalg.norm(eye - centre[shot.body])
        assert view[2] >= FLOOR_Z - 1e-9  # never from below the floor limit
        img = render(world, cam, shot.r_wc, shot.t_wc, rng, blur_px=0.7, occluders=1)
        seen = Counter(body_of[k] for k in detect_tags(img, refine_edges=False) if k in body_of)
        n += 1
        two += seen[shot.body] >= 2
        other += any(b != shot.body for b in seen)
    assert n >= 10
    assert two >= 0.7 * n, f"{two} of {n} close-ups show two or more of the block's tags"
    assert other >= 0.9 * n, f"{other} of {n} close-ups show another tagged body"

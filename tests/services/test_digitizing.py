"""Digitizing session on the simulator: points with patches, registration, journal, the port
vanishing mid-point, and the configuration files."""

from pathlib import Path

import numpy as np
import pytest
from _digitizer_support import make_device, url_backend
from scipy.spatial.transform import Rotation

from dimacq.errors import DeviceNotFoundError, SetupError
from dimacq.services.geometry.digitizer_config import load_array_config, load_jig
from dimacq.services.geometry.digitizing import DigitizingSession, JsonlJournal

CFG = load_array_config()


def place(driver, tip):
    driver.command("SIM:PROBE " + ",".join(f"{v:.6f}" for v in (*tip, 0.1, -0.1, 1.0)))


def test_session_patches_registration_and_journal(tmp_path):
    journal = JsonlJournal(tmp_path / "points.jsonl")
    rot = Rotation.from_euler("z", 30, degrees=True)
    refs = {
        f"R{i}": p
        for i, p in enumerate(
            [[-0.3, -0.3, 0.8], [0.3, -0.3, 0.9], [0.3, 0.3, 1.2], [-0.3, 0.3, 1.5], [0, 0, 1.0]]
        )
    }
    with url_backend(make_device(seed=2)) as (_, d):
        s = DigitizingSession(d, CFG.geometry(), CFG.limits(), journal=journal)
        for patch in range(2):
            shift = np.array([0.1 * patch, 0, 0])  # the array moved between patches
            for label, p in refs.items():
                place(d, np.asarray(p) - shift)
                s.digitize(label)
            place(d, np.array([0.05, 0.1, 1.1]) - shift)
            s.digitize("node 7")
            gcs = {k: rot.apply(v) for k, v in refs.items()}
            reg = s.register_patch(gcs)
            assert reg.rms_m < 0.5e-3 and reg.residual_norm_m.shape == (5,)
            if patch == 0:
                s.new_patch("moved")
        pts = s.points
        assert [p.patch for p in pts] == [0] * 6 + [1] * 6
        assert all(p.n_used == 5 for p in pts)
        both = [s.global_position(p) for p in pts if p.label == "node 7"]
        want = rot.apply([0.05, 0.1, 1.1])
        for g in both:
            assert np.linalg.norm(g - want) < 0.5e-3
        assert len(journal.read()) == 12 and journal.read()[6]["patch"] == 1
    with pytest.raises(SetupError, match=r"\['nope'\] not digitized"):
        s.register_patch({"nope": [0, 0, 0], **{k: v for k, v in list(refs.items())[:3]}})


def test_port_vanishes_mid_point_nothing_lost(tmp_path):
    device = make_device(seed=9)
    with url_backend(device) as (_, d):
        s = DigitizingSession(d, CFG.geometry(), CFG.limits(), max_reconnects=1)
        place(d, np.array([0.0, 0.0, 1.0]))
        first = s.digitize("A")
        # the cable is pulled after two shots of point B
        fired = []
        real_fire = d.fire

        def flaky_fire():
            if len(fired) == 2:
                device.unplug()
            rec = real_fire()
            fired.append(rec)
            return rec

        d.fire = flaky_fire
        place(d, np.array([0.2, 0.1, 1.3]))
        with pytest.raises(DeviceNotFoundError, match="1 points digitized so far are kept"):
            s.digitize("B")
        assert s.points == [first] and s.pending_shots("B") == 2
        device.plug()
        d.fire = real_fire
        d.reconnect(attempts=1)
        b = s.digitize("B")  # resumes with the two shots already fired
        assert b.n_shots == 5 and len(s.points) == 2
        assert np.linalg.norm(b.position_array_m - [0.2, 0.1, 1.3]) < 0.5e-3


def test_reconnects_by_itself_when_the_port_comes_back():
    device = make_device(seed=1)
    with url_backend(device) as (_, d):
        s = DigitizingSession(d, CFG.geometry(), CFG.limits())
        place(d, np.array([0.0, 0.2, 1.2]))
        real_reconnect = d.reconnect

        def replug(*a, **k):
            device.plug()
            return real_reconnect(*a, **k)

        d.reconnect = replug
        s.digitize("A", shots=2)
        device.unplug()
        p = s.digitize("B")
        assert s.reconnects == 1 and p.n_shots == 5


def test_config_files(tmp_path):
    jig = load_jig()
    assert len(jig.labels) == 24 and [int((jig.rod == r).sum()) for r in range(3)] == [8, 8, 8]
    text = (Path(__file__).resolve().parents[2] / "config/digitizer/jig.toml").read_text()
    no_z = text[: text.index('label = "Z1"')].rsplit("[[points]]", 1)[0]
    (tmp_path / "jig.toml").write_text(no_z)
    with pytest.raises(SetupError, match="rod Z has 0 indentation"):
        load_jig(tmp_path / "jig.toml")
    (tmp_path / "a.toml").write_text("schema_version = 2\n")
    with pytest.raises(SetupError, match="schema_version"):
        load_array_config(tmp_path / "a.toml")
    with pytest.raises(SetupError, match="cannot read"):
        load_array_config(tmp_path / "missing.toml")

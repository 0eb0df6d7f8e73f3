"""Nothing written outside the data folder and the rig folder: a whole request cycle (import,
acquire, calibrate, plot, report) in a fresh process whose ``HOME`` and ``TMPDIR`` are read-only
folders; afterwards they are as empty as before, and the service's own files are private."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest

from dimacq.config import default_config_file

ROOT = Path(__file__).resolve().parents[2]

CYCLE = textwrap.dedent(
    """
    import sys, time, httpx
    from pathlib import Path
    from dimacq.api import create_app
    from dimacq.api.server import BackgroundServer
    from dimacq.config import load_settings

    data, rig, example = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
    settings = load_settings(data_dir=data, token="tok", rig_file=str(rig / "rig.toml"),
                             digitizer_url="simdigitizer://confined?seed=3")
    def wait(c, job, t=240):
        end = time.monotonic() + t
        while time.monotonic() < end:
            s = c.get(f"/api/jobs/{job}").json()
            if s["state"] not in ("pending", "running"):
                return s
            time.sleep(0.1)
        raise SystemExit(f"job {job} did not end")
    srv = BackgroundServer(create_app(settings))
    srv.start(timeout_s=300)  # a loaded host: the start may take long
    c = httpx.Client(base_url=srv.url, headers={"Authorization": "Bearer tok"}, timeout=300)
    try:
        # import: a setup file and its FRFs (a UFF: spooled for the UFF reader)
        r = c.post("/api/setups/import?format=toml",
                   content=(example / "six_triax_setup.toml").read_bytes())
        assert r.status_code == 201, r.text
        r = c.post("/api/frfs/import", params={"setup_id": r.json()["id"]},
                   content=(example / "six_triax_frf.uff").read_bytes())
        assert r.status_code == 201, r.text
        fid = r.json()["id"]
        r = c.post("/api/solutions", json={"frf_id": fid})
        assert r.status_code == 201, r.text
        sol = r.json()["id"]
        # plot and report
        assert c.get(f"/api/solutions/{sol}/figure").status_code == 200
        assert c.get(f"/api/solutions/{sol}/figure?format=svg").status_code == 200
        assert c.get("/report").status_code == 200
        # acquire: the simulated article's setup, one average per input
        art = c.get("/api/simulation/article").json()
        sid = c.post("/api/setups", json=art["setup"]).json()["id"]
        body = {"setup_id": sid, "averages_per_input": 1, "min_averages": 1, "seed": 1}
        r = c.post("/api/acquisitions", json=body)
        assert r.status_code in (201, 202), r.text
        snap = wait(c, r.json()["job_id"])
        assert snap["state"] == "succeeded", snap
        # calibrate: a static run on the simulated bench
        r = c.post("/api/calibrations/runs", json={"method": "static"})
        assert r.status_code == 202, r.text
        snap = wait(c, r.json()["job_id"])
        assert snap["state"] == "succeeded", snap
    finally:
        c.close()
        srv.stop()
    print("cycle done")
    """
)


def _tree(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.slow
def test_a_whole_cycle_writes_only_in_the_data_and_rig_folders(tmp_path: Path) -> None:
    home, tmp, data, rig = (tmp_path / n for n in ("home", "tmp", "data", "rig"))
    for d in (home, tmp, rig):
        d.mkdir()
    for f in default_config_file().parent.glob("*.toml"):  # rig, bench and its setups
        shutil.copy(f, rig / f.name)
    shutil.copytree(default_config_file().parent / "calibrations", rig / "calibrations")
    home.chmod(0o555)
    tmp.chmod(0o555)  # read-only (for a service not run as root; either way checked below)
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("DIMACQ_", "MPL", "XDG_")) and k not in ("HOME", "TMPDIR")
    }
    env.update(HOME=str(home), TMPDIR=str(tmp), PYTHONDONTWRITEBYTECODE="1")
    example = ROOT / "config" / "examples"
    try:
        out = subprocess.run(
            [sys.executable, "-c", CYCLE, str(data), str(rig), str(example)],
            env=env,
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert out.returncode == 0, out.stderr[-3000:]
        assert "cycle done" in out.stdout
        assert _tree(home) == [] and _tree(tmp) == [], (_tree(home), _tree(tmp))
        assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "home", "rig", "tmp"]
    finally:
        home.chmod(0o755)
        tmp.chmod(0o755)
    assert (data / "cache" / "matplotlib").is_dir()
    h5 = list((data / "arrays").rglob("*.h5"))
    assert h5, "the acquisition wrote no HDF5 file"
    for f in h5:
        assert stat.S_IMODE(f.stat().st_mode) == 0o600, (f, oct(f.stat().st_mode))
        for folder in f.relative_to(data).parents:
            if str(folder) != ".":
                mode = stat.S_IMODE((data / folder).stat().st_mode)
                assert mode == 0o700, (folder, oct(mode))


def test_a_spool_is_emptied_only_where_no_running_process_owns_it(tmp_path: Path) -> None:
    """Two services on one data folder (the demo's chain check runs a second one): each
    keeps to ``tmp/<its pid>``; a start empties the folders of ended processes and loose
    files, never a running process's."""
    from dimacq.services.lab.lab import confine_files

    before = tempfile.tempdir
    root = tmp_path / "tmp"
    live = root / str(os.getppid())  # the test runner's parent: running
    ended = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        check=True,
        capture_output=True,
        text=True,
    )
    dead = root / ended.stdout.strip()
    for d in (live, dead):
        d.mkdir(parents=True)
        (d / "upload-spool").write_bytes(b"x")
    (root / "loose.bin").write_bytes(b"y")
    try:
        spool = confine_files(tmp_path)
        assert spool == root / str(os.getpid()) and spool.is_dir()
        assert tempfile.tempdir == str(spool)
        assert (live / "upload-spool").read_bytes() == b"x"
        assert not dead.exists() and not (root / "loose.bin").exists()
    finally:
        tempfile.tempdir = before

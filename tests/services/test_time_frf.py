"""FRFs from time data in files (UFF 58 function type 1, TDMS) through the acquisition's
estimator, against an independent answer: every output is a known FIR filter of the hammer's
force (the whole response inside the record), so its FRF is the filter's DFT exactly."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from nptdms import ChannelObject, GroupObject, TdmsWriter

from dimacq.errors import DataError
from dimacq.io.time_data import read_tdms_time, read_time_data, read_uff_time
from dimacq.model.channels import axis_name, load_names
from dimacq.services.acquisition.time_frf import frf_from_time
from dimacq.simulators.lab.scenarios import build_scenario

FS = 2000.0  # 1/FS = 5.00000e-04 exactly in the 58 record's E13.5
N = 512
AVERAGES = 3


def _setup():  # type: ignore[no-untyped-def]
    setup = build_scenario("calibration-mass-bungee").model.setup
    return setup.model_copy(update={"excitations": setup.excitations[:2]})


def _data(setup):  # type: ignore[no-untyped-def]
    """Per input: forces (averages, N) and outputs (averages, n_out, N); FIR taps per output."""
    rng = np.random.default_rng(7)
    n_out = len(setup.responses) + 6 * len(setup.load_cells)
    taps = rng.normal(size=(n_out, 8))
    pulse = np.sin(np.pi * np.arange(6) / 6)
    data = []
    for _ in setup.excitations:
        forces = np.zeros((AVERAGES, N))
        for a in range(AVERAGES):
            forces[a, 3 : 3 + pulse.size] = (150 + 50 * rng.random()) * pulse
            forces[a, 20:40] += rng.normal(size=20)  # a different spectrum each average
        outs = np.stack([np.stack([np.convolve(f, t)[:N] for t in taps]) for f in forces])
        data.append((forces, outs))
    return taps, data


def _expected(taps: np.ndarray, f: np.ndarray) -> np.ndarray:
    m = np.arange(taps.shape[1])
    return (taps[:, None, :] * np.exp(-2j * np.pi * f[None, :, None] * m / FS)).sum(-1).T


def _channels(setup):  # type: ignore[no-untyped-def]
    out = [
        ("acceleration", c.node, c.direction, axis_name(c.node, c.direction))
        for c in setup.responses
    ]
    for lc in setup.load_cells:
        out += [("reaction", lc.node, d + 1, n) for d, n in enumerate(load_names(lc.node))]
    return out


def _record58_time(node: int, d: int, ref: tuple[int, int], o_type: int, y: np.ndarray) -> str:
    """One ASCII dataset 58, function type 1 (time response), real double, even abscissa."""
    lines = [
        "    -1",
        "    58",
        f"{'Time Response':<80}",
        f"{'synthetic':<80}",
        f"{'test':<80}",
        f"{'NONE':<80}",
        f"{'NONE':<80}",
        "%5i%10i%5i%10i %10s%10i%4i %10s%10i%4i"  # noqa: UP031 (Fortran record layout)
        % (1, 0, 0, 0, "NONE", node, d, "NONE", ref[0], ref[1]),
        "%10i%10i%10i%13.5e%13.5e%13.5e" % (4, y.size, 1, 0.0, 1.0 / FS, 0.0),  # noqa: UP031
        "%10i%5i%5i%5i %-20s %-20s" % (17, 0, 0, 0, "Time", "s"),  # noqa: UP031
        "%10i%5i%5i%5i %-20s %-20s" % (o_type, 0, 0, 0, "NONE", "SI"),  # noqa: UP031
        "%10i%5i%5i%5i %-20s %-20s" % (0, 0, 0, 0, "NONE", "NONE"),  # noqa: UP031
        "%10i%5i%5i%5i %-20s %-20s" % (0, 0, 0, 0, "NONE", "NONE"),  # noqa: UP031
    ]
    cells = [f"{v:20.12e}" for v in y.tolist()]
    lines += ["".join(cells[i : i + 4]) for i in range(0, len(cells), 4)]
    lines.append("    -1")
    return "\n".join(lines) + "\n"


def _write_uff(path: Path, setup, data) -> None:  # type: ignore[no-untyped-def]
    out = []
    for e, (forces, outs) in zip(setup.excitations, data, strict=True):
        ref = (e.node, e.direction)
        for a in range(AVERAGES):
            out.append(_record58_time(e.node, e.direction, ref, 13, forces[a]))
            for k, (kind, node, d, _) in enumerate(_channels(setup)):
                o_type = 12 if kind == "acceleration" else 9
                out.append(_record58_time(node, d, ref, o_type, outs[a, k]))
    path.write_text("".join(out), encoding="ascii")


def _write_tdms(path: Path, setup, data) -> None:  # type: ignore[no-untyped-def]
    with TdmsWriter(str(path)) as w:
        for e, (forces, outs) in zip(setup.excitations, data, strict=True):
            for a in range(AVERAGES):
                group = f"{axis_name(e.node, e.direction)} average {a + 1}"
                objs = [GroupObject(group, properties={"input": axis_name(e.node, e.direction)})]
                props = {"wf_increment": 1.0 / FS}
                objs.append(ChannelObject(group, "force", forces[a], properties=props))
                for k, (_, _, _, name) in enumerate(_channels(setup)):
                    objs.append(ChannelObject(group, name, outs[a, k], properties=props))
                w.write_segment(objs)


@pytest.mark.parametrize("fmt", ["uff", "tdms"])
def test_frfs_from_time_files_equal_the_filters(tmp_path: Path, fmt: str) -> None:
    setup = _setup()
    taps, data = _data(setup)
    path = tmp_path / ("t.uff" if fmt == "uff" else "t.tdms")
    (_write_uff if fmt == "uff" else _write_tdms)(path, setup, data)
    records = read_time_data(path)
    assert len(records) == 2 * AVERAGES * (1 + 24 + 6)
    frf = frf_from_time(records, setup, source=fmt)
    assert frf.H.shape == (N // 2, 30, 2)
    want = _expected(taps, frf.frequencies_hz)
    for j in range(2):
        np.testing.assert_allclose(frf.H[:, :, j], want, rtol=1e-8, atol=1e-8)
    assert frf.coherence is not None and np.nanmin(frf.coherence) > 1 - 1e-9
    assert frf.output_kinds.count("reaction") == 6


def test_missing_input_and_bad_files_are_named(tmp_path: Path) -> None:
    setup = _setup()
    _, data = _data(setup)
    path = tmp_path / "t.uff"
    _write_uff(path, setup.model_copy(update={"excitations": setup.excitations[:1]}), data[:1])
    with pytest.raises(DataError, match=r"input .*: no time records struck there"):
        frf_from_time(read_uff_time(path), setup)
    bad = tmp_path / "b.tdms"
    with TdmsWriter(str(bad)) as w:
        w.write_segment([ChannelObject("g", "force", np.zeros(4))])
    with pytest.raises(DataError, match="no 'input' property"):
        read_tdms_time(bad)


def test_command_line_writes_frfs_solve_reads(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from dimacq.cli.main import main
    from dimacq.io.setup_file import save_setup
    from dimacq.io.uff import read_frf_uff

    setup = _setup()
    taps, data = _data(setup)
    _write_tdms(tmp_path / "t.tdms", setup, data)
    save_setup(setup, tmp_path / "setup.toml")
    out = tmp_path / "f.uff"
    assert (
        main(
            [
                "frf-from-time",
                str(tmp_path / "setup.toml"),
                str(tmp_path / "t.tdms"),
                "--frf",
                str(out),
            ]
        )
        == 0
    )
    assert "186 time records" in capsys.readouterr().out
    frf = read_frf_uff(out, setup)
    np.testing.assert_allclose(
        frf.H[:, :, 0], _expected(taps, frf.frequencies_hz), rtol=1e-6, atol=1e-6
    )
    assert (
        main(
            [
                "frf-from-time",
                str(tmp_path / "setup.toml"),
                str(tmp_path / "nope.tdms"),
                "--frf",
                str(out),
            ]
        )
        == 2
    )


def test_command_line_fft_threads_give_the_same_frfs_and_zero_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from dimacq.cli.main import main
    from dimacq.io.setup_file import save_setup
    from dimacq.io.uff import read_frf_uff

    setup = _setup()
    _, data = _data(setup)
    _write_uff(tmp_path / "t.uff", setup, data)
    save_setup(setup, tmp_path / "setup.toml")
    args = ["frf-from-time", str(tmp_path / "setup.toml"), str(tmp_path / "t.uff")]
    one = frf_from_time(read_time_data(tmp_path / "t.uff"), setup, source="t")
    import dimacq.services.acquisition.time_frf as time_frf

    threads: list[int] = []
    estimate = time_frf.estimate_frf

    def spy(*a: Any, **kw: Any) -> Any:
        threads.append(kw["workers"])
        return estimate(*a, **kw)

    monkeypatch.setattr(time_frf, "estimate_frf", spy)
    assert main([*args, "--frf", str(tmp_path / "f.uff"), "--fft-threads", "2"]) == 0
    assert threads == [2, 2]  # one estimate per input, on the threads asked for
    two = read_frf_uff(tmp_path / "f.uff", setup)
    np.testing.assert_allclose(two.H, one.H, rtol=1e-12, atol=1e-12 * np.abs(one.H).max())
    capsys.readouterr()
    with pytest.raises(SystemExit) as err:
        main([*args, "--frf", str(tmp_path / "g.uff"), "--fft-threads", "0"])
    assert err.value.code == 2
    assert "--fft-threads: '0': give a whole number of threads, 1 or more" in (
        capsys.readouterr().err
    )
    assert not (tmp_path / "g.uff").exists()

"""``python -m dimacq.simulators.digitizer --pty``: serve a simulated digitizer on a pseudo-terminal."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from dimacq.simulators.digitizer.device import SimulatedDigitizer, lab_from_config
from dimacq.simulators.digitizer.pty import PtyServer


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dimacq.simulators.digitizer", description=__doc__
    )
    parser.add_argument(
        "--pty", action="store_true", required=True, help="serve on a new pseudo-terminal"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--echo-rate", type=float, default=0.0, help="probability of an echo per shot"
    )
    parser.add_argument("--temperature", type=float, default=20.0, help="air temperature, degC")
    parser.add_argument("--rate", type=float, default=0.0, help="stream rate, shots/s (0: at once)")
    parser.add_argument(
        "--config", type=Path, default=None, help="array.toml (default config/digitizer)"
    )
    parser.add_argument(
        "--duration", type=float, default=0.0, help="stop after this many seconds (0: never)"
    )
    args = parser.parse_args(argv)
    lab = lab_from_config(args.config)
    lab.environment.echo_probability = args.echo_rate
    lab.environment.temperature_c = args.temperature
    device = SimulatedDigitizer(lab, seed=args.seed, serial="SIM-PTY", shot_rate_hz=args.rate)
    with PtyServer(device) as server:
        print(server.path, flush=True)
        print(
            f"# simulated SD-3 digitizer on {server.path} (115200 8N1); Ctrl-C stops",
            file=sys.stderr,
            flush=True,
        )
        start = time.monotonic()
        try:
            while args.duration <= 0 or time.monotonic() - start < args.duration:
                time.sleep(0.05)
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())

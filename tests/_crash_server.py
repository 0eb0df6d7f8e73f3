"""A dimacq service process for the crash-safety test: the real app and Lab on a data directory,
with the impulse acquisition rig (USB DAQ simulator) paced like a human striking.

    python tests/_crash_server.py DATA_DIR PORT TOKEN DIGITIZER_NAME [PACE_S]

Also used by ``tests/benchmarks/bench_api_status.py`` (status latency while an acquisition runs).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _lab_rig_support import impulse_rig_factory

from dimacq.api import create_app
from dimacq.api.server import serve
from dimacq.config import load_settings
from dimacq.services.lab import Lab


def main() -> None:
    data_dir, port, token, name = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
    pace_s = float(sys.argv[5]) if len(sys.argv) > 5 else 0.05
    settings = load_settings(
        data_dir=data_dir, port=port, token=token, digitizer_url=f"simdigitizer://{name}?seed=5"
    )
    lab = Lab(settings, rig_factory=impulse_rig_factory(pace_s=pace_s))
    try:
        serve(create_app(settings, lab=lab), "127.0.0.1", port, log_level="warning")
    finally:
        lab.close()


if __name__ == "__main__":
    main()

"""A small acquisition rig for the service tests: the acquisition tests' closed-form impulse
source behind the real USB DAQ simulator and driver (no load cell), with a paced operator.

``impulse_rig_factory(pace_s)`` returns a ``rig_factory`` for :class:`dimacq.services.lab.Lab`;
``IMPULSE_SETUP`` is the matching test setup (2 inputs, 3 responses). With ``imperfections``
its DAQ plays theirs (a free-running clock, a bounded FIFO); ``faults`` makes each rig's
:class:`DaqFaults`; the factory keeps every simulated DAQ it made (``factory.backends``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from _acq_support import ImpulseSource

from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.model.setup import Excitation, ResponseChannel, TestSetup
from dimacq.services.acquisition.rig import Rig
from dimacq.simulators.daq.backend import DaqFaults, DaqInput, VirtualDaqBackend
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.imperfections import NONE, Imperfections

G = 9.80665

IMPULSE_SETUP = TestSetup(
    name="impulse rig",
    responses=tuple(
        ResponseChannel(
            node=100 + k, direction=3, position_m=(0.1 * k, 0.0, 0.0), direction_gcs=(0.0, 0.0, 1.0)
        )
        for k in range(3)
    ),
    excitations=tuple(
        Excitation(
            node=10 + j, direction=1, position_m=(0.0, 0.1 * j, 0.0), direction_gcs=(1.0, 0.0, 0.0)
        )
        for j in range(2)
    ),
)


def impulse_rig_factory(
    pace_s: float = 0.0,
    double_hit_input: int | None = None,
    *,
    imperfections: Imperfections = NONE,
    faults: Callable[[], DaqFaults] | None = None,
) -> Any:
    """Rigs on the impulse source; ``double_hit_input``: every strike of that input after its
    first is a double hit (rejected)."""
    backends: list[VirtualDaqBackend] = []

    def factory(_settings: Any, _setup: TestSetup, _cfg: Any) -> Rig:
        src = ImpulseSource(n_inputs=2, n_responses=3, n_gauges=0, response_gain=0.01)
        clock = SampleClock()
        wiring = {j: DaqInput(j, 2.25e-3) for j in range(2)}
        wiring.update({2 + k: DaqInput(2 + k, 0.1 / G) for k in range(3)})
        imp = imperfections
        backend = VirtualDaqBackend(
            src,
            wiring,
            clock=clock,
            free_running=imp.daq_free_running,
            time_scale=imp.daq_time_scale,
            fifo_bytes=imp.daq_fifo_bytes,
            faults=faults() if faults is not None else None,
        )
        backends.append(backend)
        dev = DaqDevice.open(backend=backend)
        # back on the bus after a re-enumeration (the simulator's fault): the same backend
        task = DaqTask(dev, reopen=lambda: DaqDevice.open(backend=backend))
        for j in range(2):
            task.add_force_channel(j, f"{10 + j}+X force", 2.25, range_v=0.5)
        for k in range(3):
            task.add_accel_channel(2 + k, f"{100 + k}+Z", 100.0)
        task.configure_timing(src.sample_rate_hz, 256)
        lock = threading.Lock()
        struck = [0, 0]

        def operator(j: int, at: int) -> None:
            if pace_s:
                time.sleep(pace_s)  # an engineer takes time between strikes
            with lock:
                src.excite(j, backend.world_sample(at))
                if j == double_hit_input and struck[j] > 0:
                    src.excite(j, backend.world_sample(at) + 40)
                struck[j] += 1

        return Rig(
            daq=task,
            input_channels=["10+X force", "11+X force"],
            response_channels=["100+Z", "101+Z", "102+Z"],
            operator=operator,
            closers=[lambda: task.device.close()],
        )

    factory.backends = backends  # type: ignore[attr-defined]
    return factory


def struck_inputs_factory(**kw: Any) -> Callable[[Any, TestSetup, Any], Rig]:
    """The impulse rig striking the setup's inputs (a subset: redo / append) on their own
    hammer channels (input node 10 → hammer 0, 11 → hammer 1); ``kw`` to
    :func:`impulse_rig_factory` (its simulated DAQs: ``factory.backends``)."""
    inner = impulse_rig_factory(**kw)

    def factory(settings: Any, setup: TestSetup, cfg: Any) -> Rig:
        rig = inner(settings, setup, cfg)
        which = [e.node - 10 for e in setup.excitations]
        rig.input_channels = [f"{10 + k}+X force" for k in which]
        strike = rig.operator
        assert strike is not None
        rig.operator = lambda j, at: strike(which[j], at)
        return rig

    factory.backends = inner.backends  # type: ignore[attr-defined]
    return factory

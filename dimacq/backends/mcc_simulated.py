"""Backend ``daq = "mcc-usb-simulated"``: the USB-1808X driver on simulated units.

The virtual lab (:class:`~dimacq.backends.simulated.SimulatedWorld`, cabled as the rig file
says) behind :class:`~dimacq.simulators.mcc.backend.Mcc1808Backend`, a pyusb backend with as
many USB-1808X units as the rig file's inputs need (8 each; serials from ``[daq] units`` or the
simulator's own, cabled in its order), master's clock cabled to the slaves, their FPGAs not loaded at power-up. The
driver opens them exactly as ``"mcc-usb"`` does (:func:`dimacq.backends.mcc_usb.open_units`),
loading the simulated lab's FPGA image (of the vendor image's form and length: the twin's
Spartan-6 takes it as it takes MCC's). The load cell simulators count the master's clock.
"""

from __future__ import annotations

from dimacq.backends.base import DeviceContext
from dimacq.backends.mcc_usb import open_units
from dimacq.backends.simulated import imperfections, world
from dimacq.drivers.mcc import protocol as p
from dimacq.drivers.mcc.driver import MccTask
from dimacq.simulators.mcc.backend import Mcc1808Backend, lab_fpga_image

__all__ = ["open_daq"]


def open_daq(ctx: DeviceContext) -> MccTask:
    """The table entry ``daq = "mcc-usb-simulated"``."""
    w = world(ctx)
    rig = ctx.rig_file
    n_units = max(1, len(rig.daq.units), max(w.wiring, default=0) // p.N_AI + 1)
    imp = imperfections(ctx)
    backend = Mcc1808Backend(
        w.source,
        w.wiring,
        n_units=n_units,
        serials=list(rig.daq.units) or None,
        clock=w.clock,
        free_running=imp.daq_free_running,
        time_scale=imp.daq_time_scale,
        seed=0 if ctx.seed is None else ctx.seed,
        adaptive=imp.daq_adaptive_time_lapse,
    )
    w.backend = backend  # what the world's operator strikes on (the master's clock)
    where = f"daq = 'mcc-usb-simulated' (scenario {w.scenario!r})"
    # the virtual lab's units are cabled in the simulator's order when [daq] units is empty
    cabled = [u.serial for u in backend.units]
    task = open_units(
        ctx, backend, where, (lab_fpga_image(), "the simulated lab's USB_1808.bin"), cabled
    )
    if ctx.setup is not None:
        ctx.operator = w.operator(ctx)
    ctx.fixed.update({"hit_delay_samples": w.lab.block_samples, "block_samples": 512})
    return task

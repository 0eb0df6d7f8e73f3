"""Load cells read as DAQ channels: gauges (or six conditioned F/T outputs) sampled with the
accelerometers on the DAQ's one clock (:mod:`dimacq.drivers.daq_loadcell.driver`)."""

from dimacq.drivers.daq_loadcell.driver import ChannelDaq, DaqChannelLoadCell, DaqFeed, DaqSplitter

__all__ = ["ChannelDaq", "DaqChannelLoadCell", "DaqFeed", "DaqSplitter"]

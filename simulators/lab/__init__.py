"""The virtual lab: physics of the simulated test article, its supports, transducers and excitation.

This is the one place the simulated physics lives; every device simulator (digitizer, load cell,
DAQ) is fed from here.
"""

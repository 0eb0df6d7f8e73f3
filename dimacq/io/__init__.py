"""File formats: UFF interchange (:mod:`.uff`) and setup files (:mod:`.setup_file`)."""

from dimacq.io.setup_file import load_setup, save_setup
from dimacq.io.uff import read_frf_uff, read_uff_test, write_frf_uff, write_uff_test

__all__ = [
    "load_setup",
    "read_frf_uff",
    "read_uff_test",
    "save_setup",
    "write_frf_uff",
    "write_uff_test",
]

"""Universal File Format (UFF) interchange through pyuff: whole tests and dataset 58 FRFs.

The module moved whole into :mod:`dimacq.io.uff.reading`; this package re-exports its names
where they were imported from before.
"""

from dimacq.io.uff.reading import (
    ORDINATE_TYPES,
    UffSource,
    _common_axis,
    _Record,
    check_uff_geometry,
    dump_uff,
    read_frf_uff,
    read_uff_test,
    write_frf_uff,
    write_uff_test,
)

__all__ = [
    "ORDINATE_TYPES",
    "UffSource",
    "_Record",
    "_common_axis",
    "check_uff_geometry",
    "dump_uff",
    "read_frf_uff",
    "read_uff_test",
    "write_frf_uff",
    "write_uff_test",
]

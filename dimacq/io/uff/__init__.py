"""Universal File Format (UFF) interchange through pyuff: whole tests and dataset 58 FRFs.

Modules
-------
- :mod:`.datasets`: the datasets read (164 units, 2420/18 coordinate systems, 2411/15 nodes, 58
  FRF records), their layout, ordinate types and unit conversion to SI.
- :mod:`.reading`: a whole test (:func:`read_uff_test`) or the FRFs of a setup
  (:func:`read_frf_uff`) from a file, its content or a stream; the geometry from the records.
- :mod:`.writing`: a whole test (:func:`write_uff_test`), only the FRFs (:func:`write_frf_uff`),
  their bytes (:func:`dump_uff`), the geometry check (:func:`check_uff_geometry`).

The binary 58 records are read without pyuff by :mod:`dimacq.io._uff_read`.

Non-geometric setup fields (reference point, length unit, known properties, labels) have no place
in UFF: the reader takes them from its keyword arguments; ``setup.name`` travels as the 2420 part
name. Load cells with ``sign="on_support"`` are written negated as ``"on_structure"``.

The names below are importable from this package as they were from the module it replaces.
"""

from dimacq.io.uff.datasets import ORDINATE_TYPES, Record
from dimacq.io.uff.reading import UffSource, common_axis, read_frf_uff, read_uff_test
from dimacq.io.uff.writing import check_uff_geometry, dump_uff, write_frf_uff, write_uff_test

__all__ = [
    "ORDINATE_TYPES",
    "Record",
    "UffSource",
    "check_uff_geometry",
    "common_axis",
    "dump_uff",
    "read_frf_uff",
    "read_uff_test",
    "write_frf_uff",
    "write_uff_test",
]

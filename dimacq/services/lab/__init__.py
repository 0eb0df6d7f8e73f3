"""The lab service: one small service per resource, composed by a thin :class:`Lab`.

========================  ===========================================================
module                    resource
========================  ===========================================================
``lab.py``                :class:`Lab` (composition, status, jobs in the database)
``lab_tests.py``          tests: article, operator, date, notes; archive; their setups
``devices.py``            devices: digitizer, DAQ, load cells
``geometry.py``           digitizing, registration, orientation, lines of action
``store.py``              test store: setups, FRF sets, solutions
``solving.py``            analysis: solve, the figure of a stored solution
``acquisitions.py``       impact acquisitions (jobs), averages
``calibrations.py``       load cell calibrations
``studies.py``            sensitivity studies (jobs)
========================  ===========================================================
"""

from dimacq.services.lab.devices import DeviceInfo
from dimacq.services.lab.lab import Lab, LabStatus
from dimacq.services.lab.store import frf_from_arrays, frf_to_arrays

__all__ = ["DeviceInfo", "Lab", "LabStatus", "frf_from_arrays", "frf_to_arrays"]

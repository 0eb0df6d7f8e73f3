"""Services: orchestration of devices and the numerical pipeline, grouped by workflow.

================  ==========================================================================
package           workflow
================  ==========================================================================
``geometry/``     digitizing sessions, the digitizer's configuration and self-test, trust in
                  a registration
``acquisition/``  impact sessions, strike detection, stream alignment, rigs, FRFs from time
                  data
``solve/``        the analysis (estimation, modal correction, cross-checks, verdict) and
                  planning studies
``calibration/``  load-cell bench calibration, the inertial calibration mass, circular check
``lab/``          the lab service: one small service per resource, jobs, persistence
================  ==========================================================================

``lab`` composes the others; ``calibration`` runs acquisitions; ``acquisition``, ``solve`` and
``geometry`` do not import each other (import-linter contract ``services-by-workflow``).
"""

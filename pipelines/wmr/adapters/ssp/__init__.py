"""The closed loop as an SSP 1.0 package, for co-simulation masters we did not write.

:mod:`wmr.adapters.ssp.export` writes ``wmr ssp export``'s package: the robot FMU and the controller
FMU in ``resources/``, ``SystemStructure.ssd`` with their connections, the scenario's
parameters as one parameter set (``.ssv``) per component, and a default experiment.
:mod:`wmr.adapters.ssp.package` reads such a package back; :mod:`wmr.adapters.ssp.cosim` runs it in
libcosim
(``wmr ssp run``) and logs it to the MCAP layout of ``wmr run``.  ``docs/ssp.md`` says how to
run it in libcosim, fmpy and OMSimulator and how closely each follows ``wmr run``.
"""

from wmr.adapters.ssp.export import CONTROLLER, ROBOT, export_ssp

__all__ = ["CONTROLLER", "ROBOT", "export_ssp"]

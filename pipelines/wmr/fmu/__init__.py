"""From the Modelica source to FMI 2.0 and FMI 3.0 co-simulation FMUs, and the FMU as a plant."""

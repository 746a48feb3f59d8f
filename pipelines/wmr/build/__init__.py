"""Build time: Modelica source -> pymoca -> explicit ODE -> CasADi C -> zig/gcc -> FMI 2.0 and 3.0
FMUs, their model descriptions, documentation and cross-check layout.
"""

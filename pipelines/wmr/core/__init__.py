"""The core, numpy only: the physics, the signal layout, energies, the plant protocol, the closed
loop and its result, the controllers, the sensor models and estimators.  No files, no FMI.
"""

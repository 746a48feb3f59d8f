"""The FMUs at run time through fmpy: the robot FMU as a plant, the controller FMU as a controller,
variable maps for other tools' robots, the archive check.
"""

"""wmr-cosim: co-simulation and log analysis of a two-wheeled differential-drive robot."""

__version__ = "0.1.0"

"""The robot as it is really localised: sensor models between plant and stabiliser, and the
estimators that feed the stabiliser (``docs/sensing.md``).

* :mod:`wmr.sensing.config`: the ``[sensors]`` table of a scenario (:class:`SensorConfig`);
* :mod:`wmr.sensing.models`: GPS-like position fixes, a compass, wheel encoders;
* :mod:`wmr.sensing.ekf`: the odometry + fixes extended Kalman filter with latency handling;
* :mod:`wmr.sensing.estimator`: :class:`Sensing`, stepped by the master loop.
"""

from wmr.sensing.config import SensorConfig, preset, sensor_config
from wmr.sensing.estimator import Sensing, SensingRecord

__all__ = ["Sensing", "SensingRecord", "SensorConfig", "preset", "sensor_config"]

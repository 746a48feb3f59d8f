"""The robot as it is really localised: sensor models between plant and stabiliser, and the
estimators that feed the stabiliser (``docs/sensing.md``).

* :mod:`wmr.core.sensing.config`: the ``[sensors]`` table of a scenario (:class:`SensorConfig`);
* :mod:`wmr.core.sensing.models`: GPS-like position fixes, a compass, wheel encoders;
* :mod:`wmr.core.sensing.ekf`: the odometry + fixes extended Kalman filter with latency handling;
* :mod:`wmr.core.sensing.estimator`: :class:`Sensing`, stepped by the master loop.
"""

from wmr.core.sensing.config import SensorConfig, preset, sensor_config
from wmr.core.sensing.estimator import Sensing, SensingRecord

__all__ = ["Sensing", "SensingRecord", "SensorConfig", "preset", "sensor_config"]

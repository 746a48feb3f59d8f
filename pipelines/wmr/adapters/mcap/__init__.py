"""MCAP log of a closed-loop run: write it fast and reproducibly, read it back.

Log time = publish time = simulation time in ns from the start of the run; nothing in the file
depends on the wall clock or the host, so the same run gives the same bytes.  Messages are
protobuf (schema encoding ``protobuf``, a ``FileDescriptorSet``); each has a
``google.protobuf.Timestamp timestamp`` equal to its log time.

==========================  ==========================  ============================================
topic                       schema                      content (one message per control step)
==========================  ==========================  ============================================
``/robot/pose``             ``foxglove.PoseInFrame``    frame ``world``: position (x_m, y_m, 0),
                                                        orientation = yaw ``theta_rad`` about z
``/tf``                     ``foxglove.FrameTransform`` ``world`` -> ``base_link``, same pose
``/robot/state``            ``wmr.RobotState``          the 12 plant outputs of
                                                        :data:`wmr.core.signals.PLANT_SIGNALS`: x_m,
                                                        y_m, theta_rad (unwrapped), v_mps,
                                                        omega_radps, wheel speeds and angles,
                                                        x_G_m, y_G_m, E_kin_J
``/controller/errors``      ``wmr.ControllerErrors``    dr_m, e_s_m, e_theta_rad, alpha_rad,
                                                        beta_rad, gamma_rad
``/controller/commands``    ``wmr.Commands``            u_s_mps, u_theta_radps, their P and I terms,
                                                        omega_r/l_ref_radps, tau_r/l_nm
``/controller/points``      ``wmr.ControlPoints``       D_x_m, D_y_m, R_x_m, R_y_m
``/goal``                   ``foxglove.PoseInFrame``    the goal, once, at t = 0
==========================  ==========================  ============================================

The ``wmr.*`` messages have one double field per signal, named exactly like the column of
:data:`wmr.core.signals.SIGNALS` (units in the name), field numbers 2, 3, ... in column order; every
signal of a run is carried by exactly one of them, so the reader gives the written arrays back
bit for bit.  Metadata records: ``run`` (written first) and ``result`` (written last; status
``failed`` and ``error`` when the run raised).  Attachments: the scenario file and the FMU's
``modelDescription.xml``, as the caller gives them.  One chunk per second of simulation time.
"""

from wmr.adapters.mcap.reader import Pose2D, RunData, read_run
from wmr.adapters.mcap.schemas import (
    OPEN_LOOP_TOPICS,
    STEP_TOPICS,
    TopicLayout,
    file_descriptor_set,
    message_class,
)
from wmr.adapters.mcap.writer import McapOpener, RunLogWriter, goal_message, yaw_quaternion

__all__ = [
    "OPEN_LOOP_TOPICS",
    "STEP_TOPICS",
    "McapOpener",
    "Pose2D",
    "RunData",
    "RunLogWriter",
    "TopicLayout",
    "file_descriptor_set",
    "goal_message",
    "message_class",
    "read_run",
    "yaw_quaternion",
]

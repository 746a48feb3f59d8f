"""A robot FMU another tool made: a dynamic unicycle with its own names and units (pythonfmu).

Built by the tests with ``pythonfmu`` to check that ``wmr run --fmu ... --map ...`` drives an
FMU our build did not make.  Its conventions differ from ours on purpose:

- positions in mm, speed in km/h, wheel speeds in rpm, torques in N.cm;
- a compass heading in degrees (0 = north = our +y, clockwise positive), so that
  ``theta = pi/2 - heading * pi/180`` (a negative scale and an offset) and its yaw rate is
  clockwise positive in deg/s;
- the wheels are two decoupled inertias with viscous friction driving a unicycle (no platform
  dynamics), a different model from ours.
"""

import math

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real


class CompassUnicycle(Fmi2Slave):
    author = "wmr-cosim tests"
    description = "Dynamic unicycle, compass heading, mm, rpm, N.cm"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.wheel_radius_mm = 150.0
        self.half_track_mm = 300.0
        self.wheel_inertia = 0.3  # kg m^2 per wheel, rotor and its share of the platform
        self.friction = 0.05  # N m s/rad
        self.east0_mm = 0.0
        self.north0_mm = 0.0
        self.heading0_deg = 90.0
        self.torque_R_Ncm = 0.0
        self.torque_L_Ncm = 0.0
        self.east_mm = 0.0
        self.north_mm = 0.0
        self.heading_deg = 90.0
        self.speed_kmh = 0.0
        self.yaw_rate_cw_degps = 0.0
        self.wheel_R_rpm = 0.0
        self.wheel_L_rpm = 0.0
        self.moving = 0  # an Integer output: 1 while a wheel turns (a map must not take it)
        self._w_r = self._w_l = 0.0
        self._hdg = 0.0
        self.register_variable(Integer("moving", causality=Fmi2Causality.output,
                                       variability=Fmi2Variability.discrete))
        for name in ("wheel_radius_mm", "half_track_mm", "wheel_inertia", "friction"):
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable))
        for name in ("east0_mm", "north0_mm", "heading0_deg"):
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.fixed))
        for name in ("torque_R_Ncm", "torque_L_Ncm"):
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        for name in ("east_mm", "north_mm", "heading_deg", "speed_kmh", "yaw_rate_cw_degps",
                     "wheel_R_rpm", "wheel_L_rpm"):
            self.register_variable(Real(name, causality=Fmi2Causality.output))

    def exit_initialization_mode(self):
        self.east_mm, self.north_mm = self.east0_mm, self.north0_mm
        self._hdg = math.radians(self.heading0_deg)
        self._w_r = self._w_l = 0.0
        self._publish()

    def _publish(self):
        r, half = self.wheel_radius_mm / 1000.0, self.half_track_mm / 1000.0
        self.heading_deg = math.degrees(self._hdg)
        self.speed_kmh = 3.6 * r * (self._w_r + self._w_l) / 2.0
        # clockwise positive: the left wheel faster turns the robot right
        self.yaw_rate_cw_degps = math.degrees(r * (self._w_l - self._w_r) / (2.0 * half))
        self.wheel_R_rpm = self._w_r * 60.0 / (2.0 * math.pi)
        self.wheel_L_rpm = self._w_l * 60.0 / (2.0 * math.pi)
        self.moving = int(abs(self._w_r) + abs(self._w_l) > 1e-6)

    def _derivatives(self, s, tau_r, tau_l):
        r, half = self.wheel_radius_mm / 1000.0, self.half_track_mm / 1000.0
        _, _, hdg, w_r, w_l = s
        v = r * (w_r + w_l) / 2.0
        return (1000.0 * v * math.sin(hdg), 1000.0 * v * math.cos(hdg),
                r * (w_l - w_r) / (2.0 * half),
                (tau_r - self.friction * w_r) / self.wheel_inertia,
                (tau_l - self.friction * w_l) / self.wheel_inertia)

    def do_step(self, current_time, step_size):
        tau_r, tau_l = self.torque_R_Ncm / 100.0, self.torque_L_Ncm / 100.0
        s = (self.east_mm, self.north_mm, self._hdg, self._w_r, self._w_l)
        n = max(1, math.ceil(step_size / 1e-3))
        h = step_size / n
        def shifted(k, c):
            return [a + c * h * b for a, b in zip(s, k, strict=True)]

        for _ in range(n):  # classical Runge-Kutta, 1 ms substeps
            k1 = self._derivatives(s, tau_r, tau_l)
            k2 = self._derivatives(shifted(k1, 0.5), tau_r, tau_l)
            k3 = self._derivatives(shifted(k2, 0.5), tau_r, tau_l)
            k4 = self._derivatives(shifted(k3, 1.0), tau_r, tau_l)
            s = tuple(a + h / 6.0 * (b + 2 * c + 2 * d + e)
                      for a, b, c, d, e in zip(s, k1, k2, k3, k4, strict=True))
        self.east_mm, self.north_mm, self._hdg, self._w_r, self._w_l = s
        self._publish()
        return True

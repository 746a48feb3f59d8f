within WMR;
model WheelMotor "Driving wheel with its motor: inertia and friction (eq. 22)"
  parameter Real I(unit = "kg.m2", min = 0) = 0.01
    "Inertia of the wheel plus the motor rotor about the wheel axis, I_wm of eq. 22";
  parameter Real b(unit = "N.m.s/rad", min = 0) = 0 "Viscous motor friction coefficient";
  parameter Real tauC(unit = "N.m", min = 0) = 0 "Coulomb motor friction torque";
  parameter Real wC(unit = "rad/s", min = 1e-6) = 0.01
    "Wheel speed over which Coulomb friction reaches 76 % of tau_c (tanh smoothing)";
  input Real tau_m(unit = "N.m") "Motor torque tau_m";
  input Real omega(unit = "rad/s") "Wheel angular velocity, set by rolling without slip";
  input Real alpha(unit = "rad/s2") "Wheel angular acceleration";
  output Real tau_d(unit = "N.m") "Torque the wheel passes on to the platform, tau_d";
  Real tau_f(unit = "N.m") "Friction torque tau_f";
  Real phi(unit = "rad", displayUnit = "deg", start = 0, fixed = true) "Wheel angle";
equation
  // Coulomb friction is smoothed with tanh: the sign function has no solution at rest
  // for an explicit ODE (stiction would need a mode switch the FMU does not model).
  tau_f = b * omega + tauC * tanh(omega / wC);
  // eq. 22
  I * alpha + tau_d = tau_m - tau_f;
  der(phi) = omega;
end WheelMotor;

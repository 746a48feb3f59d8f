within WMR;
model Robot "Two-wheeled differential robot with wheel and motor dynamics (eq. 23, corrected eq. 24)"
  // The platform is inherited rather than a component: pymoca 0.12 resolves a binding such as
  // platform(m = m) in the component's own scope (platform.m = platform.m), so parameters that
  // keep the paper's names at both levels cannot be passed down by modification.
  extends Platform;
  parameter Real Iwm(unit = "kg.m2", min = 0) = 0.01 "Inertia of each wheel plus its motor rotor";
  parameter Real b_f(unit = "N.m.s/rad", min = 0) = 0 "Viscous motor friction coefficient";
  parameter Real tau_c(unit = "N.m", min = 0) = 0 "Coulomb motor friction torque";
  parameter Real w_c(unit = "rad/s", min = 1e-6) = 0.01 "Smoothing speed of the Coulomb friction (tanh)";
  input Real tau_r(unit = "N.m") "Right motor torque";
  input Real tau_l(unit = "N.m") "Left motor torque";
  output Real phi_r(unit = "rad", displayUnit = "deg") "Right wheel angle";
  output Real phi_l(unit = "rad", displayUnit = "deg") "Left wheel angle";
  output Real E_kin(unit = "J") "Kinetic energy of platform, wheels and rotors";
  WheelMotor wheelR(I = Iwm, b = b_f, tauC = tau_c, wC = w_c) "Right wheel and motor, eq. 22";
  WheelMotor wheelL(I = Iwm, b = b_f, tauC = tau_c, wC = w_c) "Left wheel and motor, eq. 22";
equation
  wheelR.tau_m = tau_r;
  wheelL.tau_m = tau_l;
  // Rolling without slip ties each wheel to the platform (eq. 3)
  wheelR.omega = omega_r;
  wheelL.omega = omega_l;
  wheelR.alpha = (der(v) + L * der(omega)) / r;
  wheelL.alpha = (der(v) - L * der(omega)) / r;
  tau_dr = wheelR.tau_d;
  tau_dl = wheelL.tau_d;
  phi_r = wheelR.phi;
  phi_l = wheelL.phi;
  // The energy whose conservation with zero torque checks eqs. 20 to 24 (errata.md)
  E_kin = 0.5 * (m * (v ^ 2 + (l * omega) ^ 2) + Ig * omega ^ 2 + Iwm * (omega_r ^ 2 + omega_l ^ 2));
  annotation (experiment(StartTime = 0, StopTime = 60, Interval = 0.01));
end Robot;

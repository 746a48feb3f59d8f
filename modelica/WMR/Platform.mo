within WMR;
partial model Platform "Rigid platform on two rolling wheels: kinematics (eqs. 1 to 9) and dynamics (eqs. 18 to 21)"
  // The model that extends this one sets tau_dr and tau_dl (the wheels' torques on the platform).
  parameter Real m(unit = "kg", min = 0) = 25 "Mass of the platform without wheels";
  parameter Real r(unit = "m", min = 1e-3) = 0.15 "Wheel radius";
  parameter Real L(unit = "m", min = 1e-3) = 0.3 "Half the distance between the wheels";
  parameter Real l(unit = "m") = 0.35 "Distance from B, the centre of the axle, to G, the centre of gravity";
  parameter Real Ig(unit = "kg.m2", min = 0) = 0.25 "Moment of inertia of the platform about G";
  parameter Real x0(unit = "m") = 0 "Initial x of B";
  parameter Real y0(unit = "m") = 0 "Initial y of B";
  parameter Real theta0(unit = "rad", displayUnit = "deg") = 0 "Initial heading";
  parameter Real v0(unit = "m/s") = 0 "Initial linear velocity of B";
  parameter Real omega0(unit = "rad/s") = 0 "Initial angular velocity";
  Real tau_dr(unit = "N.m") "Torque of the right wheel on the platform";
  Real tau_dl(unit = "N.m") "Torque of the left wheel on the platform";
  output Real x(unit = "m", start = x0, fixed = true) "x of B, the centre of the wheel axle, in the world frame";
  output Real y(unit = "m", start = y0, fixed = true) "y of B, the centre of the wheel axle, in the world frame";
  output Real theta(unit = "rad", displayUnit = "deg", start = theta0, fixed = true) "Heading, continuous (not wrapped)";
  output Real v(unit = "m/s", start = v0, fixed = true) "Linear velocity of B";
  output Real omega(unit = "rad/s", start = omega0, fixed = true) "Angular velocity of the platform";
  Real F_d(unit = "N") "Driving force F_d";
  Real tau_d(unit = "N.m") "Driving torque tau_d about B";
  output Real omega_r(unit = "rad/s", displayUnit = "rpm") "Right wheel angular velocity";
  output Real omega_l(unit = "rad/s", displayUnit = "rpm") "Left wheel angular velocity";
  output Real x_G(unit = "m") "x of G, the centre of gravity";
  output Real y_G(unit = "m") "y of G, the centre of gravity";
equation
  // eq. 7 (corrected): v_B = v e^(j theta)
  der(x) = v * cos(theta);
  der(y) = v * sin(theta);
  der(theta) = omega;
  // eq. 4: OG = OB + l e^(j theta)
  x_G = x + l * cos(theta);
  y_G = y + l * sin(theta);
  // eq. 3 solved for the wheel speeds (rolling without slip)
  omega_r = (v + L * omega) / r;
  omega_l = (v - L * omega) / r;
  // eq. 19 (corrected): tau_d = L (tau_r - tau_l) / r
  F_d = (tau_dr + tau_dl) / r;
  tau_d = L * (tau_dr - tau_dl) / r;
  // eq. 18 with the corrected eq. 16 (vdot, not v)
  F_d = m * (der(v) - l * omega ^ 2);
  tau_d = (Ig + m * l ^ 2) * der(omega) + m * l * v * omega;
end Platform;

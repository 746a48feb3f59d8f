within;
package WMR "Two-wheeled differential-drive mobile robot of Bunjaku, Stefanovski and Stankovski"
  annotation (
    version = "0.1.0",
    Documentation(info = "<html>
<p>The platform dynamics of the paper (eqs. 14 to 21) extended with the inertia and friction of
each driving wheel and its motor (eqs. 22 to 24), in the corrected forms of
<code>shared/design/errata.md</code>. <code>WMR.Robot</code> is the model that becomes the FMUs.</p>
<p>Notation: B is the centre of the wheel axle, G the centre of gravity, l = |BG|, L is half the
distance between the wheels (eq. 2), r the wheel radius.</p>
</html>"));
end WMR;

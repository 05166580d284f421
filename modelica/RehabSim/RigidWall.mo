within RehabSim;
model RigidWall "Stiff unilateral wall: spring-damper acting only while penetrating and never pulling (thesis Sec. 2.5.4, Fig. 32)"
  parameter Real x_wall(unit = "m") = 0.02 "wall position";
  parameter Integer side = 1 "+1: the wall blocks motion towards +x (x > x_wall penetrates); -1: blocks motion towards -x";
  parameter Real k_wall(unit = "N/m", min = 0) = 2e5 "wall stiffness";
  parameter Real d_wall(unit = "N.s/m", min = 0) = 500 "wall damping, acting only while penetrating";
  input Real x(unit = "m") "position of the body touching the wall (slave handle)";
  input Real v(unit = "m/s") "speed of the body touching the wall";
  output Real f_wall(unit = "N") "force of the wall on the body along +x";
  output Real pen(unit = "m") "penetration into the wall (0 when not in contact)";
equation
  pen = max(0, side * (x - x_wall));
  f_wall = -side * (if side * (x - x_wall) > 0 then max(0, k_wall * side * (x - x_wall) + d_wall * side * v) else 0);
end RigidWall;

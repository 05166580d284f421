within RehabSim.Gap;
model WithActuatorDelay "Ball-screw device of record + actuator_delay: transport delay between current command and torque, (2,3) Pade approximant; effect parameters Td (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithActuatorDelay;

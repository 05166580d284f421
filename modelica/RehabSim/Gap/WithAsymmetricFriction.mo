within RehabSim.Gap;
model WithAsymmetricFriction "Ball-screw device of record + asymmetric_friction: Coulomb and viscous friction that differ with the direction of motion; effect parameters dfc, db (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithAsymmetricFriction;

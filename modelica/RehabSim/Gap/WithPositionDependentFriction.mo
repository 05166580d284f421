within RehabSim.Gap;
model WithPositionDependentFriction "Ball-screw device of record + position_dependent_friction: Coulomb friction that varies along the travel (preload gradient, periodic variation); effect parameters kfx, dfp, lp, php (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithPositionDependentFriction;

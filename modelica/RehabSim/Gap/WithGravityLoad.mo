within RehabSim.Gap;
model WithGravityLoad "Ball-screw device of record + gravity_load: constant or position-dependent gravity force on the nut (axis not level); effect parameters alpha, kappa, m_g (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithGravityLoad;

within RehabSim.Gap;
model WithTransmissionCompliance "Ball-screw device of record + transmission_compliance: finite axial stiffness between screw and nut: a resonance the accelerometer sees; effect parameters c_tr, zeta_tr (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithTransmissionCompliance;

within RehabSim.Gap;
model WithCurrentSaturation "Ball-screw device of record + current_saturation: the driver clips the current at a limit; effect parameters i_lim (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithCurrentSaturation;

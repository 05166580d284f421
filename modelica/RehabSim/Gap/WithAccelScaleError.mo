within RehabSim.Gap;
model WithAccelScaleError "Ball-screw device of record + accel_scale_error: accelerometer scale-factor error and axis misalignment; effect parameters ds_acc, psi_acc (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithAccelScaleError;

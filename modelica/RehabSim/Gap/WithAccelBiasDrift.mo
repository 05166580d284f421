within RehabSim.Gap;
model WithAccelBiasDrift "Ball-screw device of record + accel_bias_drift: accelerometer bias drifting over the trial (thermal, first order); effect parameters b0_acc, db_acc, T_acc (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithAccelBiasDrift;

within RehabSim.Gap;
model WithCoggingTorque "Ball-screw device of record + cogging_torque: motor torque ripple periodic in motor angle; effect parameters A_cog, n_cog, phi_cog (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithCoggingTorque;

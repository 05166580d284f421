within RehabSim.Gap;
model WithBacklash "Ball-screw device of record + backlash: play between screw and nut (two-body, dead-zone contact); effect parameters backlash, k_bl, zeta_tr (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithBacklash;

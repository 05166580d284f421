within RehabSim.Gap;
model WithCurrentLoopLag "Ball-screw device of record + current_loop_lag: first-order lag of the current driver; effect parameters Tcl (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithCurrentLoopLag;

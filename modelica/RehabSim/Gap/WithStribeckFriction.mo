within RehabSim.Gap;
model WithStribeckFriction "Ball-screw device of record + stribeck_friction: static friction above Coulomb friction decaying with speed (Stribeck curve); effect parameters dfs, ws (defaults: effect off, the nominal device)"
  extends RehabSim.Gap.BallScrewDevice;
end WithStribeckFriction;

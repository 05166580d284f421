within RehabSim;
package Gap "Sim-to-real gap diagnosis: the ball-screw device of record with every effect of the catalogue (shared/spec/gap-diagnosis.md), each parameterised and off by default"
end Gap;

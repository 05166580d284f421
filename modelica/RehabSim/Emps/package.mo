within RehabSim;
package Emps "EMPS benchmark axis (Janot, Gautier, Brunot 2019): DC motor + ball screw + load in translation, with the force-side effects of the gap-diagnosis catalogue, each off by default"
end Emps;

package RehabSim "Device, sensor and human models of low-cost rehabilitation robots (Pilastro, PhD thesis, Padova 2016)"
end RehabSim;

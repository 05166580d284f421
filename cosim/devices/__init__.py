"""The devices' constants with units and their thesis references.

:mod:`cosim.devices.assumptions` lists every value the models and trials use that
the thesis does NOT give (table friction, arm impedance, grasp, accelerometer bias,
load-cell and wall stiffness, the patient models' calibration), each with where it is
used and its source or the calibration that chose it. It imports nothing from the
rest of the package (lowest floor, ``docs/architecture``).
"""

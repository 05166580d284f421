"""The ADXL335 accelerometer on the nut (thesis Table 2; model eq. 14-16: reading =
true acceleration + bias + white noise, the bias a random walk)."""
from __future__ import annotations

#: standard gravity [m/s^2] (converts the datasheet's g)
G0_M_S2 = 9.80665
#: measurement range [g] (+-)
RANGE_G = 3.6
#: sensitivity [V/g]
SENSITIVITY_V_PER_G = 0.300
#: sensitivity change with temperature [%/degC] (+-)
SENSITIVITY_TEMPCO_PCT_PER_DEGC = 0.01
#: 0 g offset change with temperature [g/degC] (+-1 mg/degC)
OFFSET_TEMPCO_G_PER_DEGC = 1e-3
#: noise density [g/sqrt(Hz)] (150 ug/sqrt(Hz))
NOISE_DENSITY_G_PER_SQRT_HZ = 150e-6
#: bandwidth of the x/y axes [Hz]
BANDWIDTH_HZ = 1600.0
#: sampling rate of the real-time loop [Hz]
SAMPLE_RATE_HZ = 1000.0

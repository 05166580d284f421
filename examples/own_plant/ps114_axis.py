"""PS-114 linear axis, exported with pythonfmu (``pythonfmu build -f ps114_axis.py``).

A made-up product's 1-DOF ball-screw axis in the vendor's own names and units: motor
current in mA, load force in N, shaft angle in deg, carriage position in mm.
J w' = Kt i - b w - fc sgn(w) + F lead / (2 pi), Coulomb friction that sticks at w = 0.
"""
import math

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

IN, OUT, PAR = Fmi2Causality.input, Fmi2Causality.output, Fmi2Causality.parameter


class PS114Axis(Fmi2Slave):
    author = "PS-114 team (example)"
    description = "PS-114 axis: current in mA, angles in deg, carriage in mm"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.s = {"motor_current": 0.0, "load_force": 0.0, "shaft_angle": 0.0,
                  "shaft_speed": 0.0, "encoder_angle": 0.0, "carriage_pos": 0.0,
                  "carriage_vel": 0.0, "carriage_acc": 0.0,
                  # kg m2, N m s/rad, N m, N m/A, mm/rev, counts/rev, sub-steps
                  "inertia": 1.7e-5, "visc_damping": 1.6e-5, "coulomb": 3e-3,
                  "torque_const": 0.0603, "lead_mm": 10.0, "counts": 21600.0, "n_sub": 10.0}
        self.th = 0.0
        self.w = 0.0
        for n, c in [("motor_current", IN), ("load_force", IN), ("shaft_angle", OUT),
                     ("shaft_speed", OUT), ("encoder_angle", OUT), ("carriage_pos", OUT),
                     ("carriage_vel", OUT), ("carriage_acc", OUT), ("inertia", PAR),
                     ("visc_damping", PAR), ("coulomb", PAR), ("torque_const", PAR),
                     ("lead_mm", PAR), ("counts", PAR), ("n_sub", PAR)]:
            kw = {"variability": Fmi2Variability.tunable} if c == PAR else {}
            self.register_variable(Real(n, causality=c, getter=lambda n=n: self.s[n],
                                        setter=lambda v, n=n: self.s.__setitem__(n, v), **kw),
                                   nested=False)

    def _outputs(self, acc):
        s = self.s
        r = s["lead_mm"] / (2 * math.pi)                     # mm/rad
        q = 2 * math.pi / s["counts"]
        s["shaft_angle"] = math.degrees(self.th)
        s["shaft_speed"] = math.degrees(self.w)
        s["encoder_angle"] = math.degrees(q * math.floor(self.th / q + 0.5))
        s["carriage_pos"], s["carriage_vel"], s["carriage_acc"] = (r * self.th, r * self.w,
                                                                   r * acc)

    def exit_initialization_mode(self):
        self._outputs(0.0)

    def do_step(self, t, h):
        s = self.s
        J, b, fc = s["inertia"], s["visc_damping"], s["coulomb"]
        drive = (s["torque_const"] * s["motor_current"] * 1e-3
                 + s["lead_mm"] * 1e-3 / (2 * math.pi) * s["load_force"])
        n = max(1, int(s["n_sub"]))
        dt, w0 = h / n, self.w
        for _ in range(n):
            if self.w == 0.0 and abs(drive) <= fc:
                continue                                     # sticking
            sgn = math.copysign(1.0, self.w if self.w != 0.0 else drive)
            w = (self.w + dt / J * (drive - fc * sgn)) / (1.0 + dt * b / J)
            if self.w != 0.0 and w * self.w < 0.0 and abs(drive) <= fc:
                w = 0.0                                      # stops and sticks
            self.th += dt * w
            self.w = w
        self._outputs((self.w - w0) / h)
        return True

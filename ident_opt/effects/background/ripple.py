"""``ripple``: a current (torque) ripple locked to the motor angle, its amplitude ∝ joint speed.

Back-EMF harmonics the current loop does not remove, locked to the motor angle θ_m = N q, so their amplitude
grows with speed: r_j = a_j v_j sin(c_j N_j q_j). It is part of the actual motor current, so it is both
applied to the arm (held over each tick, like the commanded torque) and logged; at 100 Hz logging its lines
alias as a real logger's would.
"""

from __future__ import annotations

from ident_opt.effects.base import Background, ca
from ident_opt.effects.keys import Key


class Ripple(Background):
    summary = "current (torque) ripple locked to the motor angle, amplitude ∝ joint speed: a v sin(c N q)"
    order = 3
    keys = {  # noqa: RUF012
        "amplitude": Key("pair", (1.3, 0.75), "N m per rad/s of joint speed, a, per joint", magnitude=True),
        "cycles": Key("pair", (1.0, 1.0), "c: cycles per motor revolution, per joint", 0.0, True),
    }

    def current(self, p: dict, robot, q, dq):
        gear = [j.gear_ratio for j in robot.joints]
        return ca.vertcat(*[p["amplitude"][j] * dq[j] * ca.sin(p["cycles"][j] * gear[j] * q[j]) for j in range(2)])


EFFECT = Ripple()

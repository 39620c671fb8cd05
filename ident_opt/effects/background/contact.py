"""``contact``: something outside the arm pushes one joint: an external torque for a while (a person, a fixture).

d_j(t) [N m, joint side] on the chosen joint j, zero on the others, for each push i = 0, 1, … (one push when
`every` is 0, else one every `every` seconds until the trial ends), with a smooth rise and fall of `ramp`:

    d_j(t) = torque · w(t − start − i·every),
    w(s) = ramp-up (1 − cos(π s / ramp)) / 2 for 0 ≤ s < ramp, 1 until `duration`, the mirror image after it.

It is a cause outside the model, not of it: the diagnosis never names it (a background term, not in the
catalogue); its truth (the keys, in the truth file's ``background``) is what `benchmarks/contacts.py` scores the
external-torque observer (`ident_opt.contact`) against. Any arm: the planar two-link arm's and an n-joint chain's
simulators add d to the applied torque (the logged torque is the drive's alone).
"""

from __future__ import annotations

import math

from ident_opt.effects.base import Background, np
from ident_opt.effects.keys import Key


class Contact(Background):
    summary = "an external torque on one joint for a while (a push; repeated every `every` s when > 0)"
    order = 3
    keys = {  # noqa: RUF012
        "joint": Key("joint", 1, "the joint it pushes: 1-based index or name"),
        "torque": Key("float", 5.0, "N m, the push's size (signed)", None, magnitude=True, maximum=1e4),
        "start": Key("float", 3.0, "s, when the first push starts"),
        "duration": Key("float", 0.5, "s, how long each push lasts, ramps included", 0.0, True),
        "ramp": Key("float", 0.05, "s, its rise and fall"),
        "every": Key("float", 0.0, "s, the period of repeated pushes (0: one push)"),
    }
    disturbs = True
    #: Unlike the other background terms, it acts on any arm (`simulator.chain` adds it too).
    any_arm = True

    def is_active(self, p: dict, coulomb) -> bool:
        return p["torque"] != 0.0

    def windows(self, p: dict, end: float) -> list[tuple[float, float]]:
        """The pushes' (start, end) [s] within a trial of `end` seconds."""
        starts = [p["start"]]
        if p["every"] > 0:
            starts = list(np.arange(p["start"], end, p["every"]))
        return [(float(s), float(s) + p["duration"]) for s in starts if s < end]

    def profile(self, p: dict, t):
        """d on the pushed joint [N m] at times t [s] (module doc)."""
        t = np.asarray(t, dtype=float)
        out = np.zeros_like(t)
        ramp = min(p["ramp"], 0.5 * p["duration"])
        for a, b in self.windows(p, float(t[-1]) + 1e-9 if t.size else 0.0):
            s = np.clip(np.minimum(t - a, b - t), 0.0, None)
            w = np.ones_like(t) if ramp <= 0 else 0.5 * (1 - np.cos(math.pi * np.minimum(s, ramp) / ramp))
            out += np.where((t >= a) & (t <= b), w, 0.0)
        return p["torque"] * out

    def disturbance(self, p: dict, n: int, dt: float, rng, joints: int = 2):
        out = np.zeros((n, joints))
        if n:
            out[:, int(p["joint"]) - 1] = self.profile(p, np.arange(n) * dt)
        return out


EFFECT = Contact()

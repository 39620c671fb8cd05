"""The simulator's background realism terms: what a real flexible arm does that no diagnosis is asked to name.

One module per term (presliding stiction, a slow torque drift, a motor-angle-locked current ripple, and a contact:
an external push for a while, on any arm, which `ident_opt.contact` detects), each
defining ``EFFECT``, a `base.Background`: its keys (the same ``NAME:key=value`` syntax as the catalogue) and
its part in the closed loop (`simulator.background` iterates them). They make the default simulated trial
resemble the real one; their values go to the truth's ``background``, not its ``effects``. The modules are
found by listing the package.
"""

from __future__ import annotations

from ident_opt.effects.base import Background, discover

#: The background terms, name -> `Background`, in listing order.
BACKGROUND: dict[str, Background] = discover(__name__, __path__)

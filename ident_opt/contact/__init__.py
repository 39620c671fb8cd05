"""Contacts and collisions: the identified model watches the robot (`docs/contacts.md`).

| module        | what it holds                                                                                  |
|---------------|------------------------------------------------------------------------------------------------|
| `dynamics`    | the momentum p = M(q) dq and the bias β = g + τ_f − Cᵀdq of any arm, from its one expression of τ |
| `observer`    | the generalized-momentum observer: τ_ext per joint from q, dq, τ (no acceleration)             |
| `thresholds`  | `Thresholds`: per joint moving / resting, calibrated on collision-free trials; the persistence |
| `alarm`       | the alarm's state machine (persistence, release, settling) and the alarms of a trial           |
| `detect`      | `detect`: the fit, the calibration (false alarms per minute held out), the observer per trial  |
| `watch`       | the observer and its alarm one sample at a time, for `online --stream` (no learning from a push) |
| `casadi_step` | `observer_step` as one CasADi Function (the generated C's), π and the thresholds baked in      |

What `ident-opt detect` writes is `ident_opt.report.detect`'s; the simulator's cause is the background term
`ident_opt.effects.background.contact`.
"""

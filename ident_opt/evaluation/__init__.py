"""Every fit and every model scored on held-out data: the studies behind `compare` and `identify`, and the two
studies that measure the tool's own rules in simulation.

- `compare`: the nominal model beside OLS and the arm's consistent fits (parameters, consistency, held-out errors).
- `identify`: every model (RR, DM, PBR, CPBR, each ± GMR) under every protocol on the problem's trials.
- `constraints`: where the physical-consistency constraints matter, on short trials with a known truth.
- `cutoff_study` (trials from `cutoff_plant`): where the derivative cut-off rule and the recommended fit stand, on
  a plant they were not tuned on.

Each returns a data object; `ident_opt.report` writes it.
"""

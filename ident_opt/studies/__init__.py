"""Studies: the experiments behind every report. Each computes and returns a data object; none writes a file
or prints (`ident_opt.report` does that, one writer per study).

| module          | study                                                                                    |
|-----------------|------------------------------------------------------------------------------------------|
| `protocols`     | every model fitted on a training part, scored on a held-out part (paper, chrono, cross-trial) |
| `identify`      | every model under every protocol on the problem's trials, GMR variants, the parameters    |
| `seeds`         | the paper's seed study: estimators fitted on shuffled splits                             |
| `compare`       | the nominal model vs OLS and the arm's consistent fits: parameters, consistency, held-out errors |
| `constraints`   | where the physical-consistency constraints matter: short trials with a known truth       |
| `audit`         | the paper's datasheet model under both conventions, against its own fit                  |
| `online_replay` | offline fit, then the rest of the trial replayed sample by sample; the batch check       |
| `calibration`   | the simulator's default trial against the real exp1                                      |
| `online_codegen`| the generated `pi_update` C against the Python online path, and its cost per update      |
| `online_service`| the streaming service's figures: stream vs batch, the GMR guard, the C update            |
| `excitation`    | Fourier excitation designs (D-, cond-optimal) as CasADi NLPs under the problem's limits  |
| `discrimination`| T-optimal designs that separate two candidate causes                                     |
| `excitation_proof` | the designs proved in the simulator against MERIt-like and random trajectories        |
| `trust`         | warnings: cut-off sensitivity, OLS vs IV, the angle convention                           |
| `ship`          | the model `codegen` ships and its check against Python                                  |
"""

#: The held-out metrics every study reports, per joint (the keys of `ident_opt.metrics.all_metrics`).
METRICS = ("rmse", "nmse", "nmse_range")

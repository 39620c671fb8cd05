"""Where fits are made: estimators of the parameters π, and the one fit the tool stands behind.

| module        | what it holds                                                                                |
|---------------|----------------------------------------------------------------------------------------------|
| `stats`       | `Stats`: YᵀY, Yᵀτ, τᵀτ and n per joint, accumulated in one chunked pass (they add up)          |
| `fit`         | `LinearFit` (π, standard errors, active constraints) and the least-squares algebra            |
| `base`        | base parameters: what the regressor determines, OLS on them, the rest reported as undetermined |
| `constrained` | the physically consistent fit (M(q) ≻ 0 as LMIs, signs from parameter kinds): a conic program  |
| `physical`    | the plausible consistent fit of an n-joint arm (a log-det prior toward the URDF)              |
| `bounded`     | bounded least squares, warm-started: the online re-solve                                      |
| `nlp`         | the NLP on the planar arm's physical parameters (CasADi + IPOPT)                              |
| `iv`          | instrumental variables (IDIM-IV): no errors-in-variables bias from noisy accelerations         |
| `estimators`  | the registry: every estimator by name, the statistics each needs                             |
| `trust`       | the checks behind the choice: OLS against IV, sensitivity to the cut-off, the angle convention |
| `recommend`   | the recommended fit: the estimator and the cut-off the run's own evidence picks, with why      |

Every linear-in-π estimator works from `Stats` alone; none reads a parameter's name (`ident_opt.consistency`).
"""

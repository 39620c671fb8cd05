"""The paper's reproduction: *Hybrid Dynamics Modeling for a Flexible 2-DoF Robotic Arm* on its own robot.

| module        | what it holds                                                                            |
|---------------|------------------------------------------------------------------------------------------|
| `published`   | the paper's printed numbers (its fitted π, its tables)                                    |
| `protocols`   | the evaluation protocols: the paper's shuffled 70/30 over its seeds, chronological, cross-trial |
| `seeds`       | the paper's seed study: estimators fitted on shuffled splits                              |
| `audit`       | the paper's datasheet model under both conventions, against its own fit                   |
| `calibration` | the simulator's default trial against the real exp1                                       |
"""

"""Numerics that know nothing of arms, used on every floor above (the loader, the estimators, the effects'
candidates, the diagnosis, the online stream):

| module          | what it holds                                                                               |
|-----------------|---------------------------------------------------------------------------------------------|
| `derivatives`   | velocities and accelerations from sampled angles: zero-phase filters, the cut-off read from the |
|                 | spectrum, the causal filter of the stream                                                   |
| `signals`       | rest stretches, delays, spectra and peaks, the deflection of a damped mode                   |
| `least_squares` | weighted least squares with sign constraints, variable projection over searched axes, HAC errors |
| `nlp`           | bounded nonlinear least squares of a CasADi expression with IPOPT                            |
| `damped_mode`   | the IPOPT polish of a lightly damped mode's frequency and damping (multiple shooting)          |
"""

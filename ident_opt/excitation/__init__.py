"""Plan the experiment: the trajectory to run next, a periodic Fourier motion optimised by IPOPT within the
problem's `[limits]` (`ident-opt excite`).

| module           | what it holds                                                                           |
|------------------|-----------------------------------------------------------------------------------------|
| `design`         | D-optimal and least-condition-number designs of the base parameters' information matrix  |
| `discrimination` | the motion that best tells two suspected causes apart (T-optimal)                        |
| `proof`          | the designs proved in the simulator against MERIt-like and random trajectories           |
"""

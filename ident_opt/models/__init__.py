"""Torque models: a parametric part (ridge regression on kinematics, or rigid-body dynamics with the datasheet's or
an identified π) plus a Gaussian-mixture-regression residual with its 95 % interval.

| module   | what it holds                                                                          |
|----------|----------------------------------------------------------------------------------------|
| `hybrid` | `RigidModel`, `RidgeModel`, `HybridModel` (parametric + GMR), the paper's model set      |
| `gmr`    | `GMR`: E[r | x] and Cov[r | x] from a Gaussian mixture on [x, r]                         |
"""

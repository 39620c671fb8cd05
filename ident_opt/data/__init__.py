"""Trials: one measured (or simulated) run of the arm as arrays in SI units, and how they are read.

| module        | what it holds                                                                                   |
|---------------|-------------------------------------------------------------------------------------------------|
| `dataset`     | `Dataset` (t, q, dq, ddq, τ: (N, n)), pools, splits, derivatives again at another cut-off        |
| `loader`      | a file (CSV, Excel, Parquet, ROS 2 bag) or arrays to a `Dataset`: columns, units, plausibility   |
| `derivatives` | velocities and accelerations from sampled angles: the zero-phase pipeline and its cut-off rule,  |
|               | the causal one the online stream uses                                                           |
| `rosbag`      | ROS 2 bags as trials                                                                            |
"""

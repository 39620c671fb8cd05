"""The planar two-link arm's diagnosis engine: `engine.PlanarEngine` (its nominal models, tuned on the MERIt trials)
and `families` (the candidate families of the catalogue's causes in the paper's grouped π, fitted by variable
projection, polished with IPOPT)."""

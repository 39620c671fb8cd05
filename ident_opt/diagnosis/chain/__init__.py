"""The diagnosis engine of an arm with n joints from a URDF: `engine.ChainEngine` (its nominal models, the
decimation of long trials) and `families` (the context every candidate is fitted in, `ArmContext`; the candidate
families, screened per joint on the evidence; their fits)."""

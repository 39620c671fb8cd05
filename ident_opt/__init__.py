"""ident-opt: identify, diagnose and ship the dynamics of flexible two-link robot arms."""

__version__ = "0.1.0"

"""Robot descriptions, the files `ident-opt export` writes: an identified arm (`ident_opt.arm.bodies.RobotDescription`,
realised from π by `ident_opt.arm.realise`) as a URDF with a JSON sidecar (`write_urdf`) or as a MuJoCo MJCF
(`write_mjcf`)."""

from ident_opt.descriptions.mjcf import mjcf_text, write_mjcf
from ident_opt.descriptions.urdf import identified, urdf_text, write_urdf

__all__ = ["identified", "mjcf_text", "urdf_text", "write_mjcf", "write_urdf"]

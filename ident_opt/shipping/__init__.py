"""Ship the identified arm: generated C for the controller and robot descriptions for other tools.

| module        | what it holds                                                                              |
|---------------|--------------------------------------------------------------------------------------------|
| `codegen`     | CasADi-generated C: `tau_hat`, `tau_hat_gmr`, the embedding README (templates in `templates/`) |
| `ship`        | what `codegen` ships (the fit, the GMR residual) and its check against Python                |
| `pi_update`   | the online update `pi_update` as generated C, checked against the Python online path         |
| `description` | the identified arm realised as rigid bodies (`Exported`)                                    |
| `urdf`, `mjcf`| that arm as a URDF with its JSON sidecar, or as a MuJoCo MJCF                                |

The C toolchain itself (generate, compile, load) is `ident_opt.cbuild`, shared with the arm's compiled regressors.
"""

from ident_opt.shipping.mjcf import mjcf_text, write_mjcf
from ident_opt.shipping.urdf import identified, urdf_text, write_urdf

__all__ = ["identified", "mjcf_text", "urdf_text", "write_mjcf", "write_urdf"]

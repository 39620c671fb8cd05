"""A simulated fleet on disk, for trying `ident-opt fleet` and for its benchmark (`ident_opt.fleet.simulated`, whose
module text says what is simulated):

    python benchmarks/simulate_fleet.py --problem problems/tudor_2dof.toml --out /tmp/fleet --robots 30 --days 20

Every option is checked while parsing, against `ident_opt.fleet.simulated.BOUNDS`, and again with the size limits
before any work (`check_spec`): a value outside is exit 2 naming the flag, and nothing is written.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict

from ident_opt.arguments import number
from ident_opt.errors import InputError
from ident_opt.fleet.simulated import BOUNDS, FleetSpec, simulate_fleet


def main(argv: list[str] | None = None) -> int:
    """The script: parse, simulate, print what was hidden."""
    parser = argparse.ArgumentParser(prog="python benchmarks/simulate_fleet.py", description=__doc__.split("\n")[0])
    parser.add_argument("--problem", required=True, help="problem file: the fleet's arm")
    parser.add_argument("--out", required=True, help="the fleet's root folder (missing or empty)")
    defaults = FleetSpec()
    for key, value in asdict(defaults).items():
        kind = number(type(value), *BOUNDS[key]) if key in BOUNDS else type(value)  # checked while parsing
        parser.add_argument(f"--{key.replace('_', '-')}", type=kind, default=value, help=f"default {value}")
    args = parser.parse_args(argv)
    spec = FleetSpec(**{k: getattr(args, k) for k in asdict(defaults)})
    try:
        hidden = simulate_fleet(args.problem, args.out, spec)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {spec.robots} robots × {spec.days} days to {args.out}; hidden changes:")
    for h in hidden:
        print(f"  {h.robot}: {h.cause} joint {h.joint} from {h.first_day} (size {h.size:.3g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

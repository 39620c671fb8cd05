"""`ident-opt simulate`: write a measured-style trial (the data format) from the built-in simulator.

The truth is the problem's datasheet read physically (rigid arm, symmetric viscous + Coulomb friction,
reflected rotor inertia), tracked by a 1 kHz PD + feedforward controller; effects from the catalogue of
`docs/effects.md` can be hidden in it. Beside OUT.csv the true values of everything hidden are written to
OUT.truth.json (π in the names of the armature model, effects in the diagnosis's estimate keys).

Effect syntax: --effect NAME or --effect NAME:key=value,key=value (repeatable); per-joint values are
bracketed pairs, key=[v1,v2] (quote the argument in the shell). Every effect takes scale=S (default 1),
which multiplies its magnitude; scale=0 gives the clean trial. Besides the catalogue, background terms of
a real arm that the diagnosis does not name (stiction, drift, ripple; contact, an external push on any arm)
take the same syntax; the default simulated problem uses them so that its residuals resemble the real MERIt trial's.
Without --effect, the problem's [simulate] effects are used (none if it has no [simulate] section);
with --effect, exactly the ones given.
Examples:
  ident-opt simulate --problem P --out trial.csv --effect elasticity:joint=2,frequency_hz=8 --seed 3
  ident-opt simulate --problem P --out t.csv --effect 'asymmetric_coulomb:positive=[0.8,0.4]'

The catalogue, with default magnitudes:
"""

from __future__ import annotations

import argparse

from ident_opt import outputs
from ident_opt.commands.common import add_problem_arguments, add_switches, problem_for, write_json
from ident_opt.effects import describe
from ident_opt.errors import InputError
from ident_opt.simulator import truth_path
from ident_opt.simulator.simulate import simulate
from ident_opt.simulator.trajectories import TRAJECTORIES
from ident_opt.simulator.trial import check_trial_path

#: The flags that override a key of the problem's [simulate] section: flag -> (key, type, metavar, help).
OVERRIDES = {
    "--seed": ("seed", int, None, "random seed (trajectory and noise); default: the problem's or 0"),
    "--duration": ("duration", float, "S", "trial length in seconds (default 80)"),
    "--rate": (
        "rate_hz",
        float,
        "HZ",
        "logging rate: a divisor of the 1 kHz control rate, or faster up to 5 kHz (the loop then runs at "
        "the logging rate); default 100",
    ),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (parser.description or "") + "\n" + describe()
    add_problem_arguments(parser, data=False)
    parser.add_argument(
        "--out",
        required=True,
        metavar="D.csv",
        help="the trial to write (CSV); the truth goes to D.truth.json beside it",
    )
    parser.add_argument(
        "--effect",
        action="append",
        metavar="NAME[:key=value,...]",
        help="hide an effect from the catalogue below (repeatable)",
    )
    for flag, (_, kind, metavar, text) in OVERRIDES.items():
        parser.add_argument(flag, type=kind, metavar=metavar, help=text)
    parser.add_argument(
        "--trajectory",
        choices=TRAJECTORIES,
        help="tud01: point-to-point moves with rests like MERIt's TUD01 (default); fourier: a Swevers-style "
        "excitation; mixed: 10 s blocks of the two in turn",
    )
    parser.add_argument(
        "--trajectory-file",
        metavar="T.csv",
        help="follow this trajectory instead (t, q1, q2, dq1, dq2, ddq1, ddq2; e.g. from ident-opt excite); "
        "it must cover --duration",
    )
    parser.add_argument(
        "--bandwidth",
        type=float,
        metavar="HZ",
        help="the controller's closed-loop bandwidth, which sets its PD gains (default 6)",
    )
    parser.add_argument(
        "--noise-scale",
        type=float,
        metavar="X",
        help="torque noise as a multiple of the sigma measured on the real robot (default 1)",
    )
    add_switches(
        parser,
        {
            "--current": "log motor currents i1, i2 [A] instead of torques",
            "--no-noise": "no encoder quantisation and no torque noise",
            "--exact-derivatives": "log the true dq and ddq instead of estimating them from the logged angles",
        },
    )


def run(args: argparse.Namespace) -> int:
    # The names first: a wrong suffix, or a truth file beside it that cannot be written, fail before the simulation.
    check_trial_path(args.out, "--out")
    outputs.check_file_output(truth_path(args.out), "--out's truth file")
    problem = problem_for(args, "simulate")
    if args.trajectory and args.trajectory_file:
        raise InputError("give --trajectory or --trajectory-file, not both")
    trial = simulate(
        problem,
        effects=args.effect,
        trajectory=args.trajectory_file or args.trajectory,
        duration=args.duration,
        rate_hz=args.rate,
        seed=args.seed,
        output="current" if args.current else None,
        noise=not args.no_noise,
        exact_derivatives=args.exact_derivatives,
        bandwidth_hz=args.bandwidth,
        noise_scale=args.noise_scale,
        progress=True,
    )
    path = trial.write(args.out)
    hidden = ", ".join(f"{name} {values}" for name, values in trial.truth["effects"].items()) or "none"
    track = trial.truth["tracking"]["max_error"]
    print(
        f"wrote {path} ({len(trial.frame)} samples at {trial.truth['settings']['rate_hz']:g} Hz) and {truth_path(path)}"
    )
    print(f"hidden effects: {hidden}")
    background = trial.truth.get("background") or {}
    if background:
        print("background terms: " + ", ".join(f"{name} {values}" for name, values in background.items()))
    print(f"max tracking error: {' / '.join(f'{e:.2e}' for e in track)} rad")
    write_json(args.json, {"csv": str(path), "truth_json": str(truth_path(path)), "truth": trial.truth})
    return 0

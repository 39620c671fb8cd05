"""``delay``: the torque (or current) channel lags the encoder channel.

Simulator: the logged torque at t is the applied torque at t − d (linear interpolation). Diagnosis: the
whole prediction delayed by d [s], searched by variable projection against both nominal models; a delay
shorter than `MIN_DELAY_S` is not named (sample-and-hold timing and filter mismatch produce that on a
perfect model); on an arm with n joints, nor one that falls below it when read like with like (`_like_with_like`).

No IPOPT polish, on purpose: the delay is already a continuous parameter (the prediction is delayed by
linear interpolation between samples, `signals.delayed`, i.e. the torque channel interpolated), and with β
solved exactly at every d the objective is a function of d alone, which the bounded Brent refinement
minimises to 1e-4 of the 0.15 s search range (15 µs, far below the 2 ms tolerance). A joint (d, β) NLP has
the same minimiser, and linear interpolation makes the objective's derivative jump at every whole-sample
delay, which gradient-based IPOPT handles worse than Brent's bracketing.
"""

from __future__ import annotations

from functools import partial

from ident_opt import wording
from ident_opt.effects.base import Effect, least_squares, np, relative_error, signals
from ident_opt.effects.families import ChainFamily, step
from ident_opt.effects.keys import Key

#: Shortest delay [s] that counts as a cause (the tolerance on hidden delays is 2 ms, too).
MIN_DELAY_S = 0.002
#: A hidden delay is found when the estimate is within this [s] or this relative error.
DELAY_TOL = (0.002, 0.20)
#: Longest delay the simulator accepts [s].
MAX_DELAY_S = 10.0
#: Where a delay is searched [s].
DELAY_SEARCH = (0.0, 0.15)
#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): the physical range of the estimate, as data.
PLAUSIBLE = (
    {
        "key": "seconds",
        "search": DELAY_SEARCH,
        "most": 0.1,
        "unit": "s",
        "why": "a torque or current channel lags its encoders by bus cycles and filters, a few to a few tens of "
        "milliseconds; a lag beyond 0.1 s means two logs not on one clock (a misaligned export), not a drive's lag",
    },
)


class Delay(Effect):
    summary = "the torque (or current) channel lags the encoder channel"
    order = 6
    keys = {"seconds": Key("float", 0.02, "s", magnitude=True, maximum=MAX_DELAY_S)}  # noqa: RUF012

    # ------------------------------------------------------------------ simulator: the logged torque lags
    def true_plant(self, plant, p: dict) -> None:
        plant.channel.append(partial(delayed, p["seconds"]))

    def chain_plant(self, plant, p: dict) -> None:
        self.true_plant(plant, p)

    def chain_families(self, ctx) -> list:
        """The whole prediction delayed by d, searched in 0–0.15 s (the measured torque read back by d while fitting,
        so that π refitted is one projection), against both nominal models."""
        return [
            ChainFamily(
                self.name,
                delay=lambda theta: theta["delay"],
                axes=lambda rate, theta: [least_squares.Axis("delay", *DELAY_SEARCH, 31)],
                estimate=lambda p, se, ctx: ({"seconds": p["delay"]}, {}),
                check=_like_with_like,
            )
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        return self.draw(rng, None)

    def chain_judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        return self.judge(estimate, truth)

    # ------------------------------------------------------------------ diagnosis
    judged = ("seconds",)
    plausible = PLAUSIBLE
    resolution = (
        f"delays shorter than {1e3 * MIN_DELAY_S:g} ms (on an arm with n joints, also when read with the "
        "prediction through the torque's low-pass) are not named",
        "sample-and-hold timing and filter mismatch produce them",
    )

    def families(self, ctx) -> list:
        return [
            self.family(
                transform=_delayed_prediction,
                axes=lambda rate: [least_squares.Axis("delay", *DELAY_SEARCH, 31)],
                estimate=lambda p, se, ctx: ({"seconds": p["delay"]}, {}),
            )
        ]

    def resolved(self, estimate: dict, dt: float) -> bool:
        return estimate["seconds"] >= max(MIN_DELAY_S, 0.5 * dt)

    def sentence(self, d, base: str, gain: str) -> str:
        lag = np.array(d.evidence[d.baseline]["lag_s"]) * 1e3
        delay = wording.num(1e3 * d.estimate["seconds"], "ms")
        return (
            f"The measured torque lags the encoder channel: a delay of {delay} "
            f"(cross-correlation lag of the {base} model: {wording.pair(lag, 'ms')}); {gain}"
        )

    def draw(self, rng, robot) -> dict:
        return {"seconds": rng.uniform(0.01, 0.04)}

    def judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        d, t = estimate["seconds"], truth["seconds"]
        return [(abs(d - t) <= DELAY_TOL[0] or relative_error(d, t) <= DELAY_TOL[1], relative_error(d, t))]


def _like_with_like(predict, theta: dict, ctx, params: dict | None = None) -> tuple[dict, str | None]:
    """The delay read again with the candidate's prediction through the low-pass the measured torque went through
    (`ArmContext.lowpass`). The fit compares the filtered torque with a prediction from the filtered angles, and
    where the model is not linear in them (a friction's sign at every reversal: the filter smooths the measured step,
    the prediction keeps it sharp) the two differ by a few ms of apparent lag on a perfect model. One Gauss–Newton
    step from the fitted d on the rest-demeaned training residual r ≈ −δ ṗ, joints weighted as the fit weighs them;
    the candidate is unresolved when that reading falls below the delay's own floor."""
    tr, d = ctx.train, float(theta["delay"])
    dt = step(tr)
    p = ctx.lowpass(predict(tr), tr)
    r = ctx.demean(tr.tau - p, tr)
    dp = ctx.demean(np.gradient(p, dt, axis=0), tr)
    w = np.asarray(ctx.weights, dtype=float)[None, :]
    curvature = float(np.sum(w * dp**2))
    if curvature <= 0.0:
        return {}, None
    reading = d - float(np.sum(w * r * dp)) / curvature
    floor = max(MIN_DELAY_S, 0.5 * dt)
    if reading < floor:
        return {"seconds_like_with_like": reading}, (
            f"read with the prediction through the torque's low-pass, the delay is {1e3 * reading:.2f} ms "
            f"(< {1e3 * floor:g} ms): the filter's smoothing of the friction's steps, not a lagging channel"
        )
    return {"seconds_like_with_like": reading}, None


def _delayed_prediction(offset, X, names: list[str], theta: dict, step: float) -> tuple:
    """The whole prediction (offset and columns) delayed by θ's delay on a grid of step `step` [s]."""
    d = theta["delay"]
    return signals.delayed(offset, d, step), signals.delayed(X, d, step), names


def delayed(seconds: float, t: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """τ (N, n) at the ticks t [s] as a channel lagging by `seconds` logs it: what is logged at t was applied
    at t − d (linear interpolation; held at the start before that)."""
    return np.column_stack([np.interp(t - seconds, t, tau[:, j]) for j in range(tau.shape[1])])


EFFECT = Delay()
